"""The synthetic scenes' camera rig and the rays of its pixels (``ftgspp synth``).

Rays are generated with the camera model of ``ftgspp.data.scene.Camera``: pixel
(row i, col j) is centred at (x=j, y=i); ray directions are scaled so that their
camera-z component is 1, so the hit parameter ``t`` *is* the camera z-depth.
"""

from __future__ import annotations

import numpy as np

from ftgspp.data.scene import Camera


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, -1.0, 0.0])) -> np.ndarray:
    """World-to-camera rotation (OpenCV axes) of a camera at ``center`` looking at ``target``."""
    z = target - center
    z = z / np.linalg.norm(z)
    y = -up - (-up @ z) * z  # image down = world down projected off the viewing axis
    y = y / np.linalg.norm(y)
    x = np.cross(y, z)
    return np.stack([x, y, z])  # rows are the camera axes in world coordinates


def make_rig(n_cameras: int, width: int, height: int, hfov_deg: float, arc_deg: float,
             radius: float, target: np.ndarray, eye_height: float) -> list[Camera]:
    """Cameras on a horizontal arc around ``target``, all looking at it.

    ``cam00`` sits at the middle of the arc (the held-out test view); the others are
    numbered left to right. Heights alternate by +-0.1 to give a vertical baseline.
    """
    focal = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    K = np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    angles = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, n_cameras))
    middle = n_cameras // 2
    order = [middle] + [k for k in range(n_cameras) if k != middle]
    cams = []
    for idx, k in enumerate(order):
        a = angles[k]
        center = target + radius * np.array([np.sin(a), 0.0, -np.cos(a)])
        center[1] = eye_height + (0.0 if k == middle else 0.1 * (-1) ** k)
        R = look_at(center, target)
        cams.append(Camera(f"cam{idx:02d}", K.copy(), R, -R @ center, width, height))
    return cams


def pixel_rays(cam: Camera, supersample: int = 1) -> np.ndarray:
    """World ray directions with unit camera-z, ``[H*s, W*s, 3]``.

    Sub-pixel ``a`` of pixel (i, j) sits at ``y = i + (a + 0.5)/s - 0.5`` (same in x), so
    ``s = 1`` gives the pixel centres and ``reshape(H, s, W, s)`` groups each pixel's samples.
    """
    s = supersample
    x = (np.arange(cam.width * s) + 0.5) / s - 0.5
    y = (np.arange(cam.height * s) + 0.5) / s - 0.5
    xx, yy = np.meshgrid(x, y)
    d_cam = np.stack([(xx - cam.K[0, 2]) / cam.K[0, 0], (yy - cam.K[1, 2]) / cam.K[1, 1], np.ones_like(xx)], -1)
    return d_cam @ cam.R  # = (R^T d_cam^T)^T
