"""Google Immersive layout (Broxton et al. 2020): per-camera videos or frames + ``models.json``.

Conventions, with their sources:

- ``models.json`` (the publisher's README, github.com/augmentedperception/deepview_video_dataset)
  is a list of camera dicts: ``name`` (``camera_0001`` ...), ``width``, ``height`` (pixels,
  written as floats), ``focal_length`` (one value, pixels), ``principal_point`` [cx, cy],
  ``radial_distortion`` [k1, k2, 0], ``orientation`` (a rotation vector), ``position`` (the
  camera centre), ``pixel_aspect_ratio`` (1.0) and ``projection_type`` ("fisheye").
- Lens: the README's projection is equidistant fisheye with a radial polynomial in the angle,
  r = f theta (1 + k1 theta^2 + k2 theta^4): OpenCV's fisheye model (``cv2.fisheye``) with
  k3 = k4 = 0, as SpacetimeGaussians reads it (tests/data/test_immersive.py reproduces the
  README's worked example through ``cv2.fisheye.projectPoints``). Missing ``projection_type``
  means fisheye; any other type, a ``pixel_aspect_ratio`` other than 1 or a non-zero third
  radial term is refused: neither the README nor public code defines them.
- Pose: R = Rodrigues(orientation), world-to-camera [R | -R position].
- Undistortion, as SpacetimeGaussians' ``script/pre_immersive_undistorted.py`` makes its
  "_undist" scenes: ``cv2.fisheye.initUndistortRectifyMap`` onto a pinhole with the focal
  length x ``FOCAL_SCALE`` (0.5), the same principal point and the same size, then
  ``cv2.remap`` (bicubic, black outside the fisheye image). The returned ``Camera`` is that
  pinhole (``dist=None``). The maps are cached as ``.npy`` under ``map_dir`` (the loader puts
  them in ``<cache>/undistort/``, beside the decoded frames), keyed by the calibration.
- Evaluation (SpacetimeGaussians, ``dataset_readers.readColmapSceneInfoImmersive``): cameras
  sorted by name, the first (``camera_0001``) held out; 50-frame segments of the 300 frames
  (04_Truck: 150); scenes 01_Welder, 02_Flames, 04_Truck, 09_Alexa, 10_Alexa, 11_Alexa,
  12_Cave. ``conf/data/immersive.yaml`` sets them; ``docs/datasets.md`` has the details.

Frames: ``<name>/<frame>.png|jpg|jpeg`` when that folder exists (frames as SpacetimeGaussians
extracts them, ``0.png`` ...), else ``<name>.mp4``; frames ``[0, count)`` without a gap.
Cameras come from ``models.json``, ordered by name; a video without an entry is ignored
(the README: some scenes miss a few cameras), an entry without frames is an error. fps: the
given value, else the videos', else 30.

Use ``ftgspp.data.load.load_scene``; ``read_immersive`` is its Immersive part.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import cv2
import numpy as np

from ftgspp.data.dynerf import DEFAULT_FPS, natural_key, probe_video, read_video
from ftgspp.data.easyvolcap import IMAGE_EXTS, read_image
from ftgspp.data.scene import Camera, save_npy_atomic
from ftgspp.data.source import SceneSource, kept_cameras
from ftgspp.errors import InputError

MODELS_FILE = "models.json"
FOCAL_SCALE = 0.5  # SpacetimeGaussians' "_undist" scenes
REQUIRED = ("name", "width", "height", "focal_length", "principal_point", "radial_distortion",
            "orientation", "position")
PROJECTIONS = ("fisheye",)


@dataclass(frozen=True)
class FisheyeCamera:
    """One ``models.json`` entry as an OpenCV fisheye camera (``x_cam = R X + T``)."""

    name: str
    K: np.ndarray  # [3, 3] focal_length, principal_point
    D: np.ndarray  # [4] cv2.fisheye coefficients (k1, k2, 0, 0)
    R: np.ndarray  # [3, 3] world-to-camera
    T: np.ndarray  # [3] = -R @ position
    width: int
    height: int

    def pinhole(self, focal_scale: float = FOCAL_SCALE) -> Camera:
        """The undistorted camera: focal x ``focal_scale``, same principal point and size."""
        K = self.K.copy()
        K[0, 0] *= focal_scale
        K[1, 1] *= focal_scale
        return Camera(name=self.name, K=K, R=self.R, T=self.T, width=self.width, height=self.height)

    def undistort_maps(self, pinhole: Camera) -> np.ndarray:
        """float32 ``[2, H, W]``: fisheye pixel (x, y) sampled by each pixel of ``pinhole``."""
        mx, my = cv2.fisheye.initUndistortRectifyMap(
            self.K, self.D, np.eye(3), pinhole.K, (pinhole.width, pinhole.height), cv2.CV_32FC1
        )
        return np.stack([mx, my])


def read_models(path: Path) -> list[FisheyeCamera]:
    """The cameras of ``models.json``, sorted by name; any malformed field is an ``InputError``."""
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        entries = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise InputError(path, f"cannot read as JSON ({' '.join(str(err).split())})") from None
    if not isinstance(entries, list) or not entries:
        raise InputError(path, "expected a non-empty JSON list of camera dicts")
    cameras = [_camera(path, i, e) for i, e in enumerate(entries)]
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(path, f"camera {dup} is listed twice")
    return sorted(cameras, key=lambda c: natural_key(c.name))


def _camera(path: Path, i: int, entry: object) -> FisheyeCamera:
    if not isinstance(entry, dict):
        raise InputError(path, f"entry {i} is not a camera dict")
    name = entry.get("name")
    if not isinstance(name, str) or not name or "/" in name:
        raise InputError(path, f"entry {i}: 'name' must be a camera name like camera_0001, got {name!r}")
    for field in REQUIRED:
        if field not in entry:
            raise InputError(path, f"camera {name}: missing field '{field}'")

    def numbers(field: str, sizes: tuple[int, ...]) -> np.ndarray:
        value = entry[field]
        flat = value if isinstance(value, list) else [value]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in flat):
            kind = "a number" if sizes == (1,) else "numbers"
            raise InputError(path, f"camera {name}: '{field}' must be {kind}, got {value!r}")
        want = "one number" if sizes == (1,) else f"a list of {' or '.join(map(str, sizes))} numbers"
        if isinstance(value, list) == (sizes == (1,)) or len(flat) not in sizes:
            raise InputError(path, f"camera {name}: '{field}' must be {want}, got {value!r}")
        arr = np.asarray(flat, dtype=np.float64)
        if not np.isfinite(arr).all():
            raise InputError(path, f"camera {name}: '{field}' contains NaN or Inf")
        return arr

    width, height, focal = (numbers(f, (1,))[0] for f in ("width", "height", "focal_length"))
    for field, v in (("width", width), ("height", height)):
        if v < 1 or v != round(v):
            raise InputError(path, f"camera {name}: '{field}' must be a positive whole number of pixels, got {v:g}")
    if focal <= 0:
        raise InputError(path, f"camera {name}: 'focal_length' must be positive, got {focal:g}")
    cx, cy = numbers("principal_point", (2,))
    radial = numbers("radial_distortion", (2, 3, 4))
    if np.any(radial[2:] != 0):
        raise InputError(path, f"camera {name}: 'radial_distortion' terms after k1, k2 must be 0, got "
                               f"{radial.tolist()} (the publisher's fisheye model has k1, k2 only)")
    orientation = numbers("orientation", (3,))
    position = numbers("position", (3,))
    projection = entry.get("projection_type", "fisheye")
    if projection not in PROJECTIONS:
        raise InputError(path, f"camera {name}: 'projection_type' {projection!r} is not supported "
                               f"(supported: {', '.join(PROJECTIONS)})")
    if "pixel_aspect_ratio" in entry and not math.isclose(numbers("pixel_aspect_ratio", (1,))[0], 1.0,
                                                          abs_tol=1e-9):
        raise InputError(path, f"camera {name}: 'pixel_aspect_ratio' {entry['pixel_aspect_ratio']!r} is not "
                               "supported (only 1: the publisher's projection uses one focal length)")
    K = np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])
    D = np.array([radial[0], radial[1], 0.0, 0.0])
    R = cv2.Rodrigues(orientation.reshape(3, 1))[0]
    return FisheyeCamera(name, K, D, R, -R @ position, int(width), int(height))


@dataclass(frozen=True)
class _Frames:
    """Where one camera's frames are: a video, or a folder of numbered images."""

    video: Path | None
    images: dict[int, Path]  # {frame id: path} when there is no video
    folder: Path

    def image_count(self) -> int:
        """Images ``[0, n)`` present without a gap."""
        n = 0
        while n in self.images:
            n += 1
        return n

    def limit_file(self, count: int) -> Path:
        return self.video if self.video is not None else self.folder / f"{count}.png"


def _frames_of(root: Path, name: str) -> _Frames:
    folder = root / name
    if folder.is_dir():
        images = {}
        for entry in os.scandir(folder):
            stem, ext = os.path.splitext(entry.name)
            if stem.isdigit() and ext.lower() in IMAGE_EXTS:
                images[int(stem)] = Path(entry.path)
        if images:
            return _Frames(None, images, folder)
    video = root / f"{name}.mp4"
    if not video.is_file():
        raise InputError(video, f"camera {name} is in {MODELS_FILE} but has no video and no frame folder {name}/")
    return _Frames(video, {}, folder)


def read_immersive(
    root: Path, drop_cameras: Sequence[str] = (), fps: float | None = None, map_dir: Path | None = None
) -> SceneSource:
    """Cameras (undistorted pinholes), frame counts and an undistorting frame reader; no frame decoded."""
    models_path = root / MODELS_FILE
    models = read_models(models_path)
    keep = kept_cameras([m.name for m in models], drop_cameras, root)
    models = [models[i] for i in keep]
    frames = [_frames_of(root, m.name) for m in models]
    counts, rates = [], []
    for m, f in zip(models, frames):
        if f.video is None:
            counts.append(f.image_count())
            continue
        count, width, height, rate = probe_video(f.video)
        if (width, height) != (m.width, m.height):
            raise InputError(f.video, f"is {width}x{height} but {MODELS_FILE} says {m.width}x{m.height}")
        counts.append(count)
        rates.append(rate)
    cameras = [m.pinhole() for m in models]

    def read_frames(cam: int, frame_ids: Sequence[int]) -> Iterator[np.ndarray]:
        maps = _cached_maps(models[cam], cameras[cam], map_dir)
        for rgb in _raw_frames(frames[cam], models[cam], frame_ids):
            yield cv2.remap(rgb, maps[0], maps[1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT)

    files = [p for f in frames for p in ([f.video] if f.video is not None else f.images.values())]
    return SceneSource(
        cameras=cameras,
        frame_counts=counts,
        limit_files=[f.limit_file(n) for f, n in zip(frames, counts)],
        fps=_fps(fps, rates),
        read_frames=read_frames,
        fingerprint_files=[models_path, *files],
    )


def _raw_frames(frames: _Frames, model: FisheyeCamera, frame_ids: Sequence[int]) -> Iterator[np.ndarray]:
    """uint8 ``[H, W, 3]`` RGB fisheye frames, size checked against ``models.json``."""
    if frames.video is not None:
        yield from read_video(frames.video, frame_ids, (model.width, model.height))
        return
    for fid in frame_ids:
        path = frames.images.get(int(fid), frames.folder / f"{int(fid)}.png")
        bgr = read_image(path)
        if bgr.shape[:2] != (model.height, model.width):
            raise InputError(path, f"is {bgr.shape[1]}x{bgr.shape[0]}, {MODELS_FILE} says {model.width}x{model.height}")
        yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _cached_maps(model: FisheyeCamera, pinhole: Camera, map_dir: Path | None) -> np.ndarray:
    """``model.undistort_maps(pinhole)``, read from / written to ``map_dir`` when given."""
    if map_dir is None:
        return model.undistort_maps(pinhole)
    key = hashlib.sha1()
    for a in (model.K, model.D, pinhole.K, np.array([pinhole.width, pinhole.height], np.float64)):
        key.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    path = Path(map_dir) / f"{model.name}-{key.hexdigest()[:12]}.npy"
    if path.is_file():
        return np.load(path)
    maps = model.undistort_maps(pinhole)
    save_npy_atomic(path, maps)
    return maps


def _fps(fps: float | None, rates: Sequence[float]) -> float:
    if fps is not None:
        if not fps > 0:
            raise InputError("data.fps", f"must be > 0, got {fps}")
        return float(fps)
    known = [r for r in rates if math.isfinite(r) and r > 0]
    return float(known[0]) if known else DEFAULT_FPS
