"""Initial 4D Gaussians from multi-view video: keyframe triangulation and velocities.

``initialize(scene, cfg.init, budget, seed)`` returns an ``InitPoints`` with exactly
``budget`` points (docs/design.md §4, "Init"); the model turns it into parameters.
"""

from ftgspp.init.points import InitPoints, depth_range, initialize, triangulate_keyframe
from ftgspp.init.velocity import knn_velocity

__all__ = ["InitPoints", "depth_range", "initialize", "knn_velocity", "triangulate_keyframe"]
