"""DyNeRF / Neural 3D Video layout: ``camNN.mp4`` videos and ``poses_bounds.npy``.

``poses_bounds.npy`` is ``[N, 17]`` (the LLFF format): per camera a 3x5 matrix flattened
row-major, then near and far. The 3x5 matrix is a camera-to-world matrix with columns
[down, right, back, centre] followed by a column (H, W, focal). Rows follow the sorted
list of the videos present in the folder. Conventions used here:

- OpenCV camera-to-world columns (x right, y down, z forward) are [P1, P0, -P2, P3].
- Principal point at the image centre, ``cx = W/2, cy = H/2``, in our coordinates where
  pixel centres are integers. This is the ray convention every NeRF/LLFF-style DyNeRF
  loader uses (ray through pixel index i has direction (i - W/2)/f).
- H, W, focal in the file describe some resolution of the video (often half of it); the
  focal length is scaled by decoded-video width / W, and the principal point is taken
  from the decoded size.
- fps from the video container (30 when it reports none); near/far of the scene are the
  smallest near and the largest far over the kept cameras.

Use ``ftgspp.data.load.load_scene``; ``read_dynerf`` is its DyNeRF half.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.data.source import SceneSource, kept_cameras
from ftgspp.errors import InputError

DEFAULT_FPS = 30.0
ROTATION_TOL = 1e-2  # max |R^T R - I| entry accepted in a pose row


def natural_key(name: str) -> list:
    """Sort key that orders ``cam2`` before ``cam10``."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def cameras_from_poses_bounds(
    poses_bounds: np.ndarray, names: Sequence[str], sizes: Sequence[tuple[int, int]] | None = None
) -> list[Camera]:
    """OpenCV cameras from LLFF rows ``[N, 17]``.

    ``sizes[i] = (width, height)`` of the decoded video; the focal length is rescaled from
    the file's (H, W) to it. Without ``sizes`` the file's own H, W are used.
    """
    cameras = []
    for i, (row, name) in enumerate(zip(poses_bounds, names)):
        m = row[:15].reshape(3, 5).astype(np.float64)
        h_file, w_file, focal = m[:, 4]
        width, height = sizes[i] if sizes is not None else (int(round(w_file)), int(round(h_file)))
        focal = focal * width / w_file
        c2w = np.stack([m[:, 1], m[:, 0], -m[:, 2]], axis=1)  # [3, 3] columns x, y, z (OpenCV)
        R = c2w.T  # world-to-camera
        T = -R @ m[:, 3]
        K = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])
        cameras.append(Camera(name=name, K=K, R=R, T=T, width=width, height=height))
    return cameras


def read_dynerf(root: Path, drop_cameras: Sequence[str] = ()) -> SceneSource:
    """Cameras, frame counts and a frame reader for a DyNeRF folder (no frames decoded)."""
    pose_file = root / "poses_bounds.npy"
    videos = sorted(root.glob("cam*.mp4"), key=lambda p: natural_key(p.stem))
    if not videos:
        raise InputError(root, "no cam*.mp4 videos (DyNeRF layout)")
    poses_bounds = _read_poses_bounds(pose_file)
    if len(poses_bounds) != len(videos):
        raise InputError(
            pose_file,
            f"has {len(poses_bounds)} camera rows but {root} has {len(videos)} videos (cam*.mp4); "
            "rows must follow the sorted list of videos",
        )
    names = [v.stem for v in videos]
    keep = kept_cameras(names, drop_cameras, root)
    videos = [videos[i] for i in keep]
    poses_bounds = poses_bounds[keep]
    names = [names[i] for i in keep]

    probes = [probe_video(v) for v in videos]  # (frame count, width, height, fps)
    sizes = []
    for video, row, (_, width, height, _) in zip(videos, poses_bounds, probes):
        h_file, w_file = row[4], row[9]
        if abs(h_file * width / w_file - height) > 1.0:
            raise InputError(
                video,
                f"is {width}x{height} but {pose_file.name} says {w_file:g}x{h_file:g} (a different aspect ratio)",
            )
        sizes.append((width, height))
    fps = _common_fps(videos, [p[3] for p in probes])
    cameras = cameras_from_poses_bounds(poses_bounds, names, sizes)

    def read_frames(cam: int, frame_ids: Sequence[int]) -> Iterator[np.ndarray]:
        return read_video(videos[cam], frame_ids, sizes[cam])

    return SceneSource(
        cameras=cameras,
        frame_counts=[p[0] for p in probes],
        limit_files=list(videos),
        fps=fps,
        read_frames=read_frames,
        fingerprint_files=[pose_file, *videos],
        near=float(poses_bounds[:, 15].min()),
        far=float(poses_bounds[:, 16].max()),
    )


NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file (numpy.lib.format)


def _read_poses_bounds(path: Path) -> np.ndarray:
    """``[N, 17]`` float64, checked: shape, finite values, rotations, positive sizes and bounds."""
    if not path.is_file():
        raise InputError(path, "file not found")
    with open(path, "rb") as f:
        head = f.read(16)
    if not head.startswith(NPY_MAGIC):  # np.load would try it as a pickle and say so
        start = f"it starts with {head!r}" if head else "it is empty"
        raise InputError(path, f"not a NumPy .npy file ({start}, not {NPY_MAGIC!r}); write it with numpy.save")
    try:
        pb = np.load(path, allow_pickle=False)
    except Exception as err:  # numpy raises several types for corrupt files
        detail = " ".join(str(err).split())  # one line
        raise InputError(path, f"cannot read as a .npy array ({type(err).__name__}: {detail})") from None
    if pb.ndim != 2 or pb.shape[1] != 17 or pb.shape[0] == 0 or not np.issubdtype(pb.dtype, np.number):
        raise InputError(path, f"expected a numeric N x 17 array, got shape {pb.shape} ({pb.dtype})")
    pb = pb.astype(np.float64)
    bad = ~np.isfinite(pb).all(axis=1)
    if bad.any():
        raise InputError(path, f"row {int(np.argmax(bad))} contains NaN or Inf")
    for i, row in enumerate(pb):
        m = row[:15].reshape(3, 5)
        rot = m[:, :3]
        if np.abs(rot.T @ rot - np.eye(3)).max() > ROTATION_TOL or np.linalg.det(rot) < 0:
            raise InputError(path, f"row {i}: columns [down, right, back] are not a rotation")
        if min(m[0, 4], m[1, 4], m[2, 4]) <= 0:
            raise InputError(path, f"row {i}: H, W and focal must be positive, got {m[:, 4].tolist()}")
        if not 0 < row[15] < row[16]:
            raise InputError(path, f"row {i}: expected 0 < near < far, got near={row[15]:g}, far={row[16]:g}")
    return pb


def probe_video(video: Path) -> tuple[int, int, int, float]:
    """``(frame count, width, height, fps)`` from the container, without decoding."""
    cap = cv2.VideoCapture(str(video))
    try:
        if not cap.isOpened():
            raise InputError(video, "cannot open video (missing, unreadable or corrupt)")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    finally:
        cap.release()
    if count <= 0 or width <= 0 or height <= 0:
        raise InputError(video, f"video reports {count} frames of {width}x{height}; nothing to read")
    return count, width, height, fps


def _common_fps(videos: Sequence[Path], rates: Sequence[float]) -> float:
    """The videos' frame rate (``DEFAULT_FPS`` when the container gives none); all must agree."""
    known = [(v, r) for v, r in zip(videos, rates) if math.isfinite(r) and r > 0]
    if not known:
        return DEFAULT_FPS
    ref_video, fps = known[0]
    for video, rate in known[1:]:
        if abs(rate - fps) > 0.01 * fps:
            raise InputError(video, f"runs at {rate:g} fps but {ref_video.name} at {fps:g} fps")
    return fps


def read_video(video: Path, frame_ids: Sequence[int], size: tuple[int, int]) -> Iterator[np.ndarray]:
    """Yield frames ``frame_ids`` (ascending) of ``video`` as uint8 ``[H, W, 3]`` RGB.

    ``size = (width, height)`` is checked on every frame. Any failure is an ``InputError``.
    """
    cap = cv2.VideoCapture(str(video))
    try:
        if not cap.isOpened():
            raise InputError(video, "cannot open video (missing, unreadable or corrupt)")
        pos = 0
        for fid in frame_ids:
            while pos < fid:  # skip without converting
                if not cap.grab():
                    raise InputError(video, f"decoding stopped at frame {pos}; frame {fid} is needed")
                pos += 1
            ok, bgr = cap.read()
            if not ok or bgr is None:
                raise InputError(video, f"decoding stopped at frame {pos}; frame {fid} is needed")
            pos += 1
            if bgr.shape[1::-1] != tuple(size) or bgr.ndim != 3:
                raise InputError(video, f"frame {fid} is {bgr.shape[1]}x{bgr.shape[0]}, expected {size[0]}x{size[1]}")
            yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    finally:
        cap.release()
