"""Multi-view video scenes: cameras, loaders (DyNeRF, EasyVolcap) and the synthetic generator."""

from ftgspp.data.scene import Camera, Scene

__all__ = ["Camera", "Scene"]
