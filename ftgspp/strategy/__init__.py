"""Relocation of dead Gaussians (count fixed): policies decide, ops mutate.

``policies.py`` chooses which Gaussians are dead and which alive ones they copy;
``ops.py`` changes parameters and optimizer moments under ``torch.no_grad()``.
``Relocator`` ties them to the schedule in ``StrategyConfig``.
"""

from ftgspp.strategy.relocate import Relocator

__all__ = ["Relocator"]
