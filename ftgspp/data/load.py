"""Load a multi-view video scene (DyNeRF, EasyVolcap or Google Immersive layout) into one ``Scene``.

    from ftgspp.config import DataConfig
    from ftgspp.data.load import load_scene
    scene = load_scene(DataConfig(path="data/coffee_martini", drop_cameras=["cam13"]))
    frames = scene.frames(0)  # uint8 [F, H, W, 3] RGB, decoded once, then cached on disk

The format modules (``dynerf.py``, ``easyvolcap.py``, ``immersive.py``) only read their own
files into a ``SceneSource``: full-resolution (undistorted) cameras, how many frames each
camera has, and a frame iterator. This module does what the layouts share: format detection,
the frame range, downsampling, the train/test split and where decoded frames (and Immersive's
undistortion maps, in ``<cache>/undistort/``) are cached. ``docs/datasets.md`` lists the
datasets, their layouts and evaluation conventions. Loading reads
metadata only; frames are decoded on first use. Every problem with the input is raised
as one ``InputError`` naming the file (or config key) and what is wrong.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from ftgspp.config import DataConfig
from ftgspp.data.dynerf import read_dynerf
from ftgspp.data.easyvolcap import read_easyvolcap
from ftgspp.data.immersive import MODELS_FILE, read_immersive
from ftgspp.data.scene import Camera, Scene
from ftgspp.data.source import SceneSource, match_camera
from ftgspp.errors import InputError

FORMATS = ("dynerf", "easyvolcap", "immersive")
DEFAULT_TEST_CAMERAS = ("cam00",)


def detect_format(path: str | Path) -> str:
    """The layout of scene folder ``path``: ``"dynerf"``, ``"easyvolcap"`` or ``"immersive"``."""
    root = Path(path)
    if not root.is_dir():
        raise InputError(root, "scene folder not found")
    if (root / "poses_bounds.npy").is_file() and any(root.glob("cam*.mp4")):
        return "dynerf"
    if (root / "intri.yml").is_file() and (root / "extri.yml").is_file():
        return "easyvolcap"
    if (root / MODELS_FILE).is_file():
        return "immersive"
    raise InputError(
        root,
        "unknown scene layout: expected poses_bounds.npy + cam*.mp4 (DyNeRF), "
        "intri.yml + extri.yml + images/ (EasyVolcap) or models.json + camera_*.mp4 (Immersive)",
    )


def load_scene(cfg: DataConfig) -> Scene:
    """Read the scene described by ``cfg`` (metadata only; frames decode lazily)."""
    if not cfg.path:
        raise InputError("data.path", "no scene folder given")
    root = Path(cfg.path).expanduser()
    if not root.is_dir():
        raise InputError(root, "scene folder not found")
    if not cfg.downsample >= 1:  # also rejects NaN
        raise InputError("data.downsample", f"must be >= 1, got {cfg.downsample}")
    fmt = detect_format(root) if cfg.format == "auto" else cfg.format
    if fmt not in FORMATS:
        raise InputError("data.format", f"unknown format {cfg.format!r}; expected auto, {', '.join(FORMATS)}")

    source = _read_source(fmt, root, cfg)
    names = [c.name for c in source.cameras]
    if not names:
        raise InputError(root, "no cameras left to load")
    frame_ids = _frame_range(cfg, source, names)
    cameras = source.cameras
    if cfg.downsample != 1:
        cameras = [c.scaled(1.0 / cfg.downsample) for c in cameras]
        for c in cameras:
            if c.width < 1 or c.height < 1:
                raise InputError("data.downsample", f"{cfg.downsample} leaves camera {c.name} with no pixels")
    train_ids, test_ids = split_cameras(names, list(cfg.test_cameras), root)
    name = root.resolve().name
    return Scene(
        name=name,
        root=root,
        cameras=cameras,
        frame_ids=frame_ids,
        fps=source.fps,
        train_ids=train_ids,
        test_ids=test_ids,
        decode=_decoder(source, cameras, frame_ids),
        cache_dir=_cache_dir(cfg, root, name, fmt, source),
        near=source.near,
        far=source.far,
        ground_truth=root / "gt" if (root / "gt").is_dir() else None,
    )


def _read_source(fmt: str, root: Path, cfg: DataConfig) -> SceneSource:
    if fmt == "dynerf":
        return read_dynerf(root, drop_cameras=cfg.drop_cameras)
    if fmt == "immersive":
        map_dir = _cache_base(cfg, root) / "undistort"
        return read_immersive(root, drop_cameras=cfg.drop_cameras, fps=cfg.fps, map_dir=map_dir)
    return read_easyvolcap(root, drop_cameras=cfg.drop_cameras, fps=getattr(cfg, "fps", None))


def _frame_range(cfg: DataConfig, source: SceneSource, names: list[str]) -> np.ndarray:
    """Source frame ids ``[F]`` of ``[frame_start, frame_end)``, checked against every camera."""
    start = cfg.frame_start
    if start < 0:
        raise InputError("data.frame_start", f"must be >= 0, got {start}")
    if cfg.frame_end is None:
        shortest = int(np.argmin(source.frame_counts))
        end = source.frame_counts[shortest]
        if end <= start:
            raise InputError(
                source.limit_files[shortest],
                f"camera {names[shortest]} has {end} frames, none left after data.frame_start={start}",
            )
    else:
        end = cfg.frame_end
        if end <= start:
            raise InputError("data.frame_end", f"empty frame range [{start}, {end})")
        for i, count in enumerate(source.frame_counts):
            if count < end:
                raise InputError(
                    source.limit_files[i],
                    f"camera {names[i]} has {count} frames, the frame range [{start}, {end}) needs {end}",
                )
    return np.arange(start, end, dtype=np.int64)


def split_cameras(names: Sequence[str], test_cameras: Sequence[str], root: Path) -> tuple[list[int], list[int]]:
    """Train and test camera indices.

    Test cameras are matched by name or number (``cam00`` finds ``cam00``, ``00`` or ``0``).
    When the default ``["cam00"]`` matches nothing, the first camera is held out instead;
    any other name that matches nothing is an error.
    """
    test_ids: list[int] = []
    for wanted in test_cameras:
        i = match_camera(wanted, names)
        if i is None:
            if tuple(test_cameras) == DEFAULT_TEST_CAMERAS:
                i = 0
            else:
                raise InputError(
                    "data.test_cameras", f"camera {wanted!r} not found in {root} (cameras: {', '.join(names)})"
                )
        if i not in test_ids:
            test_ids.append(i)
    train_ids = [i for i in range(len(names)) if i not in test_ids]
    if not train_ids:
        raise InputError("data.test_cameras", f"holds out every camera of {root}; none left to train on")
    return train_ids, sorted(test_ids)


def _decoder(source: SceneSource, cameras: list[Camera], frame_ids: np.ndarray) -> Callable[[int], np.ndarray]:
    """``decode(cam) -> uint8 [F, H, W, 3]`` RGB at the (downsampled) camera resolution."""

    def decode(cam: int) -> np.ndarray:
        c = cameras[cam]
        out = np.empty((len(frame_ids), c.height, c.width, 3), dtype=np.uint8)
        n = 0
        for img in source.read_frames(cam, frame_ids):
            if img.shape[:2] != (c.height, c.width):
                img = cv2.resize(img, (c.width, c.height), interpolation=cv2.INTER_AREA)
            out[n] = img
            n += 1
        if n != len(frame_ids):
            raise InputError(source.limit_files[cam], f"gave {n} frames, expected {len(frame_ids)}")
        return out

    return decode


def _cache_dir(cfg: DataConfig, root: Path, name: str, fmt: str, source: SceneSource) -> Path:
    """``<cache base>/<scene name>-<fingerprint>``.

    The fingerprint hashes the scene's resolved path and the size and mtime of its input
    files, so a regenerated scene or another scene sharing ``data.cache_dir`` never reads
    stale frames (``Scene``'s cache key only holds camera name, size and frame range).
    """
    base = _cache_base(cfg, root)
    h = hashlib.sha1(f"{root.resolve()}|{fmt}".encode())
    for f in source.fingerprint_files:
        st = f.stat()
        h.update(f"|{f.name}:{st.st_size}:{st.st_mtime_ns}".encode())
    return base / f"{name}-{h.hexdigest()[:10]}"


def _cache_base(cfg: DataConfig, root: Path) -> Path:
    """``data.cache_dir``, else ``<scene>/.ftgspp_cache``."""
    return Path(cfg.cache_dir).expanduser() if cfg.cache_dir else root / ".ftgspp_cache"
