"""Cameras and the ``Scene`` every loader returns.

A scene is a set of calibrated cameras that all saw the same time span. Frames are
decoded lazily, once per camera, and cached on disk as ``.npy`` arrays (uint8,
``[F, H, W, 3]``) so that later runs memory-map them instead of decoding video again.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

# decode(camera_index) -> uint8 [F, H, W, 3] RGB frames, already cut to the frame range and
# downsampled to the scene's resolution.
FrameDecoder = Callable[[int], np.ndarray]


@dataclass(frozen=True)
class Camera:
    """A pinhole camera in OpenCV conventions (x right, y down, z forward).

    ``x_cam = R @ X_world + T``; pixel = K @ x_cam / z.
    """

    name: str
    K: np.ndarray  # [3, 3] intrinsics in pixels, at this camera's width/height
    R: np.ndarray  # [3, 3] world-to-camera rotation
    T: np.ndarray  # [3] world-to-camera translation
    width: int
    height: int
    dist: np.ndarray | None = None  # OpenCV distortion coefficients, or None

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``[3]``."""
        return -self.R.T @ self.T

    @property
    def viewmat(self) -> np.ndarray:
        """World-to-camera 4x4 matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.T
        return m

    @property
    def projection(self) -> np.ndarray:
        """3x4 projection matrix ``K [R | T]`` (for OpenCV triangulation)."""
        return self.K @ np.hstack([self.R, self.T[:, None]])

    def scaled(self, factor: float) -> "Camera":
        """The same camera at ``factor`` times the resolution (0.5 = half size)."""
        K = self.K.copy().astype(np.float64)
        K[:2] *= factor
        # pixel centres: keep the continuous image plane aligned
        K[0, 2] = (self.K[0, 2] + 0.5) * factor - 0.5
        K[1, 2] = (self.K[1, 2] + 0.5) * factor - 0.5
        return replace(self, K=K, width=int(round(self.width * factor)), height=int(round(self.height * factor)))


@dataclass
class Scene:
    """A multi-view video scene: cameras, timestamps and lazily cached frames."""

    name: str
    root: Path
    cameras: list[Camera]
    frame_ids: np.ndarray  # [F] source frame index of each loaded frame
    fps: float
    train_ids: list[int]  # indices into ``cameras``
    test_ids: list[int]
    decode: FrameDecoder = field(repr=False)
    cache_dir: Path | None = None
    near: float | None = None  # scene depth bounds, when the format provides them
    far: float | None = None
    ground_truth: Path | None = None  # synthetic scenes: folder with depth / scene flow / trajectories
    _frames: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def times(self) -> np.ndarray:
        """Timestamp of each loaded frame in seconds, ``[F]``."""
        return self.frame_ids.astype(np.float64) / self.fps

    @property
    def n_frames(self) -> int:
        return len(self.frame_ids)

    @property
    def duration(self) -> float:
        """Time span covered by the loaded frames, in seconds (one frame interval if single)."""
        return float(self.n_frames) / self.fps

    def frames(self, cam: int) -> np.ndarray:
        """All frames of camera ``cam`` as uint8 ``[F, H, W, 3]`` (memory-mapped when cached)."""
        if cam not in self._frames:
            self._frames[cam] = self._load_cached(cam)
        return self._frames[cam]

    def image(self, cam: int, frame: int) -> np.ndarray:
        """Frame ``frame`` (index into the loaded range) of camera ``cam`` as float32 ``[H, W, 3]`` in [0, 1]."""
        return self.frames(cam)[frame].astype(np.float32) / 255.0

    def _load_cached(self, cam: int) -> np.ndarray:
        if self.cache_dir is None:
            return self.decode(cam)
        c = self.cameras[cam]
        key = f"{c.name}_{c.width}x{c.height}_f{int(self.frame_ids[0])}-{int(self.frame_ids[-1])}_n{self.n_frames}.npy"
        path = Path(self.cache_dir) / key
        if path.exists():
            return np.load(path, mmap_mode="r")
        save_npy_atomic(path, np.ascontiguousarray(self.decode(cam), dtype=np.uint8))
        return np.load(path, mmap_mode="r")


def save_npy_atomic(path: Path, arr: np.ndarray) -> None:
    """Write ``arr`` to ``path`` (.npy) so that a concurrent reader never sees half a file.

    Each writer uses its own temporary file in the same folder, then renames it over
    ``path``: runs that fill the same cache at the same time each install a whole file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.save(f, arr)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
