"""EasyVolcap layout (SelfCap, ENeRF-Outdoor): ``intri.yml``, ``extri.yml``, ``images/``.

- ``intri.yml``: ``names`` (camera names, in order), per camera ``K_<n>`` (3x3),
  ``D_<n>`` or ``dist_<n>`` (OpenCV distortion, zero when absent), optional ``H_<n>``,
  ``W_<n>`` (otherwise read from the camera's first image).
- ``extri.yml``: ``Rot_<n>`` (3x3) or ``R_<n>`` (Rodrigues vector), and ``T_<n>``;
  ``x_cam = R X + T``.
- images at ``images/<n>/<frame>.jpg|jpeg|png`` (frame written ``%06d``); frames
  ``[0, count)`` of a camera are the ones present without a gap from 0.

Both yml files are OpenCV FileStorage YAML (``%YAML:1.0``, ``!!opencv-matrix``) and are
read with ``cv2.FileStorage``. fps: an explicit value, else ``fps`` from the first of
``scene.json``, ``metadata.json``, ``gt/scene.json`` (synthetic scenes) that has one, else 30.

Distortion: OpenCV's radial-tangential model with 4, 5, 8, 12 or 14 coefficients (what
``cv2.initUndistortRectifyMap`` takes); any other count is refused, and the yml has no field
for a fisheye model (undistort such footage first). Frames of a camera with non-zero
distortion are undistorted on decode (``cv2.remap`` with maps from
``cv2.initUndistortRectifyMap``, bilinear, the same as ``cv2.undistort``) keeping the same K,
so the returned ``Camera`` is a pinhole with ``dist = None``. Keeping K is what ENeRF's own
ENeRF-Outdoor reader does (``cv2.undistort(img, K, D)``, zju3dv/ENeRF
``lib/datasets/enerf_outdoor/enerf.py``); EasyVolcap's readers default to ``dist_opt_K``, a new
K from ``cv2.getOptimalNewCameraMatrix(..., alpha=0)`` that crops the border instead.

ENeRF-Outdoor (Lin et al. 2022) as released: ``<scene>/intri.yml`` and ``extri.yml`` written
by EasyMocap (``names``, ``K_<n>``, ``dist_<n>`` [1x5], ``R_<n>`` and ``Rot_<n>``, ``T_<n>``;
no image size), 18 cameras ``00`` ... ``17`` with ``images/<n>/<frame:06d>.jpg`` (1920x1080),
and folders this reader ignores (``bkgd/``, ``bgmtv2/``, ``vhull/``, ``background.ply``). It
ships no frame rate (30 unless ``data.fps`` says otherwise). Its held-out camera and frame
range are not in the data: ``conf/data/enerf_outdoor.yaml`` and ``docs/datasets.md``.

Use ``ftgspp.data.load.load_scene``; ``read_easyvolcap`` is its EasyVolcap half.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.data.source import SceneSource, kept_cameras
from ftgspp.errors import InputError

DEFAULT_FPS = 30.0
IMAGE_EXTS = (".jpg", ".jpeg", ".png")
DIST_SIZES = (4, 5, 8, 12, 14)  # coefficient counts cv2.initUndistortRectifyMap accepts
METADATA_FILES = ("scene.json", "metadata.json", "gt/scene.json")  # gt/: our synthetic scenes


def read_easyvolcap(root: Path, drop_cameras: Sequence[str] = (), fps: float | None = None) -> SceneSource:
    """Cameras, frame counts and a frame reader for an EasyVolcap folder (no frames decoded)."""
    intri_path, extri_path = root / "intri.yml", root / "extri.yml"
    intri, extri = _open_storage(intri_path), _open_storage(extri_path)
    try:
        names = _read_names(intri, intri_path)
        keep = kept_cameras(names, drop_cameras, root)
        names = [names[i] for i in keep]
        calib = [_read_calibration(intri, intri_path, extri, extri_path, n) for n in names]
    finally:
        intri.release()
        extri.release()

    frame_files = [_list_images(root, n) for n in names]  # per camera: {frame id: path}
    frame_counts, limit_files = [], []
    for name, files in zip(names, frame_files):
        count = 0
        while count in files:
            count += 1
        ext = Counter(p.suffix for p in files.values()).most_common(1)[0][0] if files else ".jpg"
        frame_counts.append(count)
        limit_files.append(root / "images" / name / f"{count:06d}{ext}")

    cameras = []
    for name, (K, dist, R, T, width, height), files in zip(names, calib, frame_files):
        if width is None or height is None:
            if 0 not in files:
                raise InputError(root / "images" / name, f"no frame 000000 to read the size of camera {name} from")
            height, width = read_image(files[0]).shape[:2]
        cameras.append(Camera(name=name, K=K, R=R, T=T, width=width, height=height))
    dists = [d if np.any(d != 0) else None for (_, d, *_rest) in calib]

    def read_frames(cam: int, frame_ids: Sequence[int]) -> Iterator[np.ndarray]:
        return _read_frames(cameras[cam], dists[cam], frame_files[cam], root / "images" / cameras[cam].name, frame_ids)

    return SceneSource(
        cameras=cameras,
        frame_counts=frame_counts,
        limit_files=limit_files,
        fps=_scene_fps(root, fps),
        read_frames=read_frames,
        fingerprint_files=[intri_path, extri_path, *(p for files in frame_files for p in files.values())],
    )


def _open_storage(path: Path) -> cv2.FileStorage:
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        fs = cv2.FileStorage(str(path), cv2.FileStorage_READ)
    except Exception as err:  # cv2.error, or SystemError wrapping it on parse errors
        msg = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
        raise InputError(path, f"cannot parse as OpenCV FileStorage YAML ({msg})") from None
    if not fs.isOpened():
        raise InputError(path, "cannot open as OpenCV FileStorage YAML")
    return fs


def _read_names(fs: cv2.FileStorage, path: Path) -> list[str]:
    node = fs.getNode("names")
    if node.empty() or node.isNone():
        raise InputError(path, "missing key 'names'")
    if not node.isSeq() or node.size() == 0:
        raise InputError(path, "'names' must be a non-empty list of camera names")
    names = []
    for i in range(node.size()):
        item = node.at(i)
        name = item.string() if item.isString() else (str(int(item.real())) if item.isInt() else "")
        if not name:
            raise InputError(path, f"'names' entry {i} is not a camera name")
        names.append(name)
    if len(set(names)) != len(names):
        raise InputError(path, "'names' lists a camera twice")
    return names


def _read_array(fs: cv2.FileStorage, key: str) -> np.ndarray | None:
    """Matrix or number sequence stored under ``key`` as float64; None when absent."""
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        return None
    if node.isSeq():
        return np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
    if node.isInt() or node.isReal():
        return np.array([node.real()], dtype=np.float64)
    mat = node.mat()
    return None if mat is None else np.asarray(mat, dtype=np.float64)


def _require(fs: cv2.FileStorage, path: Path, key: str, sizes: tuple[int, ...], what: str = "") -> np.ndarray:
    """Array under ``key`` with one of the element counts ``sizes``, finite; else InputError."""
    arr = _read_array(fs, key)
    if arr is None:
        raise InputError(path, f"missing key '{key}'")
    if arr.size not in sizes:
        raise InputError(path, f"'{key}' has {arr.size} values, expected {' or '.join(map(str, sizes))}{what}")
    if not np.isfinite(arr).all():
        raise InputError(path, f"'{key}' contains NaN or Inf")
    return arr


def _read_calibration(
    intri: cv2.FileStorage, intri_path: Path, extri: cv2.FileStorage, extri_path: Path, name: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int | None, int | None]:
    """``(K [3,3], dist [D], R [3,3], T [3], width, height)`` of camera ``name``."""
    K = _require(intri, intri_path, f"K_{name}", (9,)).reshape(3, 3)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(intri_path, f"'K_{name}' has a non-positive focal length")
    dist_key = f"D_{name}" if _read_array(intri, f"D_{name}") is not None else f"dist_{name}"
    dist = np.zeros(5)
    if _read_array(intri, dist_key) is not None:
        dist = _require(intri, intri_path, dist_key, DIST_SIZES, " (OpenCV's radial-tangential model)").reshape(-1)
    size = []
    for key in (f"W_{name}", f"H_{name}"):
        arr = _read_array(intri, key)
        size.append(int(round(arr.reshape(-1)[0])) if arr is not None and arr.size == 1 and arr[0] > 0 else None)

    if _read_array(extri, f"Rot_{name}") is not None:
        R = _require(extri, extri_path, f"Rot_{name}", (9,)).reshape(3, 3)
    else:
        r = _require(extri, extri_path, f"R_{name}", (3, 9))
        R = r.reshape(3, 3) if r.size == 9 else cv2.Rodrigues(r.reshape(3, 1))[0]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise InputError(extri_path, f"the rotation of camera {name} is not a rotation matrix")
    T = _require(extri, extri_path, f"T_{name}", (3,)).reshape(3)
    return K, dist, R, T, size[0], size[1]


def _list_images(root: Path, name: str) -> dict[int, Path]:
    """``{frame id: path}`` of ``images/<name>/<digits>.<jpg|jpeg|png>``."""
    folder = root / "images" / name
    if not folder.is_dir():
        raise InputError(folder, f"image folder of camera {name} not found")
    files = {}
    for entry in os.scandir(folder):
        stem, ext = os.path.splitext(entry.name)
        if stem.isdigit() and ext.lower() in IMAGE_EXTS:
            files[int(stem)] = Path(entry.path)
    return files


def read_image(path: Path) -> np.ndarray:
    """uint8 ``[H, W, 3]`` BGR, or InputError."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(path, "cannot read image (missing, unreadable or corrupt)")
    return img


def _read_frames(
    cam: Camera, dist: np.ndarray | None, files: dict[int, Path], folder: Path, frame_ids: Sequence[int]
) -> Iterator[np.ndarray]:
    """Yield uint8 ``[H, W, 3]`` RGB frames, undistorted with ``dist`` when given."""
    maps = None
    if dist is not None:
        maps = cv2.initUndistortRectifyMap(cam.K, dist, None, cam.K, (cam.width, cam.height), cv2.CV_32FC1)
    for fid in frame_ids:
        fid = int(fid)
        path = files.get(fid, folder / f"{fid:06d}.jpg")
        bgr = read_image(path)
        if bgr.shape[:2] != (cam.height, cam.width):
            raise InputError(path, f"is {bgr.shape[1]}x{bgr.shape[0]}, camera {cam.name} is {cam.width}x{cam.height}")
        if maps is not None:
            bgr = cv2.remap(bgr, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _scene_fps(root: Path, fps: float | None) -> float:
    if fps is not None:
        if not fps > 0:
            raise InputError("data.fps", f"must be > 0, got {fps}")
        return float(fps)
    for name in METADATA_FILES:
        path = root / name
        if not path.is_file():
            continue
        try:
            meta = json.loads(path.read_text())
        except (OSError, ValueError) as err:
            raise InputError(path, f"cannot read as JSON ({err})") from None
        if isinstance(meta, dict) and "fps" in meta:
            value = meta["fps"]
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
                raise InputError(path, f"'fps' must be a positive number, got {value!r}")
            return float(value)
    return DEFAULT_FPS
