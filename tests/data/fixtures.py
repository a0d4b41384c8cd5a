"""Tiny scene writers for loader tests: DyNeRF and EasyVolcap folders with a known camera rig,
and Immersive folders (``models.json`` + fisheye frames of a straight 3D edge).

Every frame shows one bright Gaussian blob, drawn where the rig's OpenCV camera sees the
moving 3D point ``marker_position(t)`` (``t`` = frame / fps, seconds), on a coloured
background (R > G > B, to catch BGR/RGB swaps). The writers encode the cameras by the
formats' stated conventions with their own code, so loading a written scene and
projecting the marker is an independent check of the loaders.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ftgspp.data.scene import Camera

WIDTH, HEIGHT, FOCAL = 32, 24, 30.0
BACKGROUND_RGB = (150.0, 60.0, 20.0)
DOWN = (0.3, 1.0, 0.2)  # world direction the rig's cameras see as down: a generic rotation
MARKER_GAIN, MARKER_SIGMA = 100.0, 1.5  # added to every channel; blob size in pixels


def look_at_camera(
    name: str,
    center: Sequence[float],
    target: Sequence[float] = (0.0, 0.0, 0.0),
    width: int = WIDTH,
    height: int = HEIGHT,
    focal: float = FOCAL,
    dist: np.ndarray | None = None,
) -> Camera:
    """OpenCV camera at ``center`` looking at ``target``, its y axis (down) tilted towards ``DOWN``."""
    c = np.asarray(center, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - c
    z /= np.linalg.norm(z)
    x = np.cross(DOWN, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    K = np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])
    return Camera(name=name, K=K, R=R, T=-R @ c, width=width, height=height, dist=dist)


def ring_cameras(names: Sequence[str], radius: float = 4.0) -> list[Camera]:
    """Cameras on an arc in front of the origin, at varying heights, all looking at it."""
    cams = []
    for i, name in enumerate(names):
        a = np.deg2rad(-40.0 + 80.0 * i / max(len(names) - 1, 1))
        center = (radius * np.sin(a), 0.6 * ((i % 3) - 1), -radius * np.cos(a))
        cams.append(look_at_camera(name, center, target=(0.05, -0.03, 0.1)))
    return cams


def marker_position(t: float) -> np.ndarray:
    """The marker's world position at time ``t`` seconds, ``[3]``."""
    return np.array([-0.2, 0.1, 0.1]) + np.array([2.0, -1.0, 0.5]) * t


def project(cam: Camera, X: np.ndarray) -> np.ndarray:
    """Pixel ``[2]`` of world point ``X`` in ``cam``, through its distortion if it has one."""
    if cam.dist is not None:
        rvec = cv2.Rodrigues(cam.R)[0]
        uv, _ = cv2.projectPoints(X.reshape(1, 1, 3), rvec, cam.T.astype(np.float64), cam.K, cam.dist)
        return uv.reshape(2)
    x = cam.K @ (cam.R @ X + cam.T)
    return x[:2] / x[2]


def render_frame(cam: Camera, t: float) -> np.ndarray:
    """uint8 ``[H, W, 3]`` RGB frame of ``cam`` at time ``t``."""
    u, v = project(cam, marker_position(t))
    yy, xx = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    blob = MARKER_GAIN * np.exp(-0.5 * ((xx - u) ** 2 + (yy - v) ** 2) / MARKER_SIGMA**2)
    img = np.asarray(BACKGROUND_RGB)[None, None, :] + blob[..., None]
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def marker_centroid(rgb: np.ndarray) -> np.ndarray:
    """Sub-pixel centre ``[2]`` (x, y) of the blob in a uint8 RGB frame."""
    lum = rgb.astype(np.float64).sum(axis=2)
    weight = np.clip(lum - np.median(lum) - 30.0, 0.0, None)
    yy, xx = np.mgrid[0 : rgb.shape[0], 0 : rgb.shape[1]]
    return np.array([(weight * xx).sum(), (weight * yy).sum()]) / weight.sum()


def llff_rows(
    cameras: Sequence[Camera], near: Sequence[float], far: Sequence[float], hwf_scale: float = 1.0
) -> np.ndarray:
    """poses_bounds rows ``[N, 17]``: c2w columns [down, right, back, centre], (H, W, focal), near, far."""
    rows = []
    for cam, n, f in zip(cameras, near, far):
        c2w = np.linalg.inv(cam.viewmat)[:3]  # [3, 4] columns: x right, y down, z forward, centre
        m = np.zeros((3, 5))
        m[:, 0] = c2w[:, 1]  # down
        m[:, 1] = c2w[:, 0]  # right
        m[:, 2] = -c2w[:, 2]  # back
        m[:, 3] = c2w[:, 3]
        m[:, 4] = np.array([cam.height, cam.width, cam.K[0, 0]]) * hwf_scale
        rows.append(np.concatenate([m.ravel(), [n, f]]))
    return np.array(rows)


def write_video(path: Path, frames: Sequence[np.ndarray], fps: float) -> None:
    """RGB frames -> mp4 (codec mp4v)."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened(), "OpenCV cannot write mp4v videos here"
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()


def write_dynerf(
    root: Path,
    cameras: Sequence[Camera] | None = None,
    n_frames: int = 6,
    fps: float = 30.0,
    frames_per_camera: dict[str, int] | None = None,
    hwf_scale: float = 1.0,
) -> Path:
    """A DyNeRF folder: ``camNN.mp4`` + ``poses_bounds.npy`` (near = 1 + i/10, far = 9 + i)."""
    cameras = list(cameras) if cameras is not None else ring_cameras([f"cam{i:02d}" for i in range(4)])
    root.mkdir(parents=True, exist_ok=True)
    for cam in cameras:
        n = (frames_per_camera or {}).get(cam.name, n_frames)
        write_video(root / f"{cam.name}.mp4", [render_frame(cam, k / fps) for k in range(n)], fps)
    near = [1.0 + i / 10 for i in range(len(cameras))]
    far = [9.0 + i for i in range(len(cameras))]
    np.save(root / "poses_bounds.npy", llff_rows(cameras, near, far, hwf_scale))
    return root


def _yml_matrix(key: str, a: np.ndarray) -> str:
    a = np.atleast_2d(np.asarray(a, dtype=np.float64))
    data = ", ".join(f"{v:.17g}" for v in a.ravel())
    return f"{key}: !!opencv-matrix\n   rows: {a.shape[0]}\n   cols: {a.shape[1]}\n   dt: d\n   data: [ {data} ]\n"


def write_easyvolcap(
    root: Path,
    cameras: Sequence[Camera] | None = None,
    n_frames: int = 6,
    fps: float | None = None,
    ext: str = ".png",
    rotation: str = "rodrigues",  # rodrigues (R_n) | matrix (Rot_n)
    dist_key: str = "D",  # D | dist
    write_size: bool = True,
) -> Path:
    """An EasyVolcap folder: ``intri.yml``, ``extri.yml``, ``images/<n>/<frame:06d><ext>``.

    The yml files are written as text in OpenCV's ``%YAML:1.0`` FileStorage format, as
    EasyVolcap writes them. ``fps`` (when given) goes to ``scene.json``; frames are
    rendered at ``fps`` or 30.
    """
    cameras = list(cameras) if cameras is not None else ring_cameras([f"{i:02d}" for i in range(4)])
    root.mkdir(parents=True, exist_ok=True)
    intri = "%YAML:1.0\n---\nnames:\n" + "".join(f'   - "{c.name}"\n' for c in cameras)
    extri = "%YAML:1.0\n---\n"
    for cam in cameras:
        intri += _yml_matrix(f"K_{cam.name}", cam.K)
        intri += _yml_matrix(f"{dist_key}_{cam.name}", cam.dist if cam.dist is not None else np.zeros((1, 5)))
        if write_size:
            intri += f"H_{cam.name}: {cam.height}\nW_{cam.name}: {cam.width}\n"
        if rotation == "rodrigues":
            extri += _yml_matrix(f"R_{cam.name}", cv2.Rodrigues(cam.R)[0])
        else:
            extri += _yml_matrix(f"Rot_{cam.name}", cam.R)
        extri += _yml_matrix(f"T_{cam.name}", cam.T.reshape(3, 1))
    (root / "intri.yml").write_text(intri)
    (root / "extri.yml").write_text(extri)
    rate = fps if fps is not None else 30.0
    if fps is not None:
        (root / "scene.json").write_text(json.dumps({"fps": fps}))
    for cam in cameras:
        folder = root / "images" / cam.name
        folder.mkdir(parents=True, exist_ok=True)
        for k in range(n_frames):
            bgr = cv2.cvtColor(render_frame(cam, k / rate), cv2.COLOR_RGB2BGR)
            params = [cv2.IMWRITE_JPEG_QUALITY, 98] if ext in (".jpg", ".jpeg") else []
            assert cv2.imwrite(str(folder / f"{k:06d}{ext}"), bgr, params)
    return root


def write_scene(layout: str, root: Path, **kwargs) -> Path:
    """``write_dynerf`` or ``write_easyvolcap`` (``layout`` "dynerf" | "easyvolcap") with ``kwargs``."""
    return write_dynerf(root, **kwargs) if layout == "dynerf" else write_easyvolcap(root, **kwargs)


# --- Google Immersive: models.json + fisheye frames ------------------------------------------------

# The camera of the publisher's README (github.com/augmentedperception/deepview_video_dataset) and
# its worked example: world point (0.5, 0.5, 10) lands on pixel README_PIXEL.
README_VIEW = {
    "name": "camera_0001",
    "position": [0.003311238794086777, 0.000126384684934784, 0.42421246053630285],
    "orientation": [-0.03295944563072383, 0.02964606619481096, -0.03337751007195316],
    "focal_length": 1111.3638715594666,
    "pixel_aspect_ratio": 1.0,
    "principal_point": [1284.7296468363463, 925.4651609728676],
    "height": 1920.0,
    "width": 2560.0,
    "radial_distortion": [0.0970525284520715, -0.01708587111009977, 0.0],
    "projection_type": "fisheye",
}
README_POINT, README_PIXEL = (0.5, 0.5, 10.0), (1377.85525, 1017.61440)


def immersive_view(name: str, center: Sequence[float], target: Sequence[float], scale: float = 1 / 16) -> dict:
    """A ``models.json`` entry: the README camera's lens at ``scale`` x its resolution, looking at ``target``."""
    cam = look_at_camera(name, center, target)
    view = dict(README_VIEW, name=name, position=[float(v) for v in center],
                orientation=cv2.Rodrigues(cam.R)[0].ravel().tolist())
    for key in ("focal_length", "width", "height"):
        view[key] = README_VIEW[key] * scale
    view["principal_point"] = [(c + 0.5) * scale - 0.5 for c in README_VIEW["principal_point"]]
    return view


def fisheye_rays(view: dict, supersample: int = 1) -> np.ndarray:
    """World ray directions ``[H*s, W*s, 3]`` of a view's (sub)pixels, by the README's lens model.

    r / f = theta (1 + k1 theta^2 + k2 theta^4) is inverted with Newton steps (not OpenCV).
    """
    s, f = supersample, view["focal_length"]
    k1, k2 = view["radial_distortion"][:2]
    x = (np.arange(int(view["width"]) * s) + 0.5) / s - 0.5 - view["principal_point"][0]
    y = (np.arange(int(view["height"]) * s) + 0.5) / s - 0.5 - view["principal_point"][1]
    xx, yy = np.meshgrid(x / f, y / f)
    rd = np.hypot(xx, yy)
    theta = rd.copy()
    for _ in range(12):
        g = theta * (1 + k1 * theta**2 + k2 * theta**4) - rd
        theta -= g / (1 + 3 * k1 * theta**2 + 5 * k2 * theta**4)
    scale = np.sin(theta) / np.maximum(rd, 1e-12)
    d_cam = np.stack([xx * scale, yy * scale, np.cos(theta)], -1)
    R = cv2.Rodrigues(np.asarray(view["orientation"], dtype=np.float64))[0]
    return d_cam @ R  # world = R^T d_cam


def edge_frame(view: dict, point: Sequence[float], direction: Sequence[float], dark: float = 60.0,
               bright: float = 200.0, supersample: int = 8) -> np.ndarray:
    """uint8 RGB fisheye frame of the 3D line ``point + s direction``: ``dark`` on one side, ``bright``
    on the other (the side of the plane through the camera centre and the line), antialiased."""
    normal = np.cross(np.asarray(point) - np.asarray(view["position"]), np.asarray(direction))
    side = (fisheye_rays(view, supersample) @ normal > 0).astype(np.float64)
    h, w = int(view["height"]), int(view["width"])
    frac = side.reshape(h, supersample, w, supersample).mean(axis=(1, 3))
    grey = np.round(dark + (bright - dark) * frac).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


def write_immersive(root: Path, frames: dict[str, list[np.ndarray]], views: Sequence[dict], fps: float = 30.0,
                    as_images: bool = False) -> Path:
    """An Immersive folder: ``models.json`` + ``<name>.mp4`` (lossless FFV1), or ``<name>/<i>.png``."""
    from ftgspp.data.synthetic.formats import write_video as write_lossless

    root.mkdir(parents=True, exist_ok=True)
    (root / "models.json").write_text(json.dumps(list(views), indent=1))
    for name, images in frames.items():
        if as_images:
            (root / name).mkdir(exist_ok=True)
            for i, img in enumerate(images):
                assert cv2.imwrite(str(root / name / f"{i}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        else:
            write_lossless(root / f"{name}.mp4", np.stack(images), fps)
    return root
