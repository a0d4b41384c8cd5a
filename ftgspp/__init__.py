"""FreeTimeGS++: dynamic (4D) Gaussian splatting in PyTorch.

The trainer library. It depends on torch, numpy and OpenCV only and never imports
hydra or mlflow; the study harness (``harness/``) wraps it.
"""

__version__ = "0.1.0"
