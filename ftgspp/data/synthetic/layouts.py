"""Synthetic scenes seen through real lenses: the Immersive and ENeRF-Outdoor layouts (``ftgspp synth``).

    ftgspp synth --out data/synth_immersive --layout immersive          # fisheye + models.json
    ftgspp synth --out data/synth_outdoor --layout enerf_outdoor        # EasyVolcap + distortion

Each camera of the rig (``rig``) gets a lens; RGB frames are ray-cast through it
(every (sub)pixel's ray comes from the OpenCV lens model: ``cv2.fisheye.undistortPoints`` or
``cv2.undistortPoints``), so loading a scene really undistorts. The lens is chosen so that the
loader's undistorted camera *is* the rig's pinhole camera; ground truth (``gt/``) is rendered
for those pinholes, so it lines up with the loaded frames as in the plain layouts, and a
``dynerf`` scene with the same settings shows the same content in the same cameras. Each
camera is ray-cast twice (pinhole for ``gt/``, lens for RGB), so these layouts take longer.

- ``immersive``: OpenCV fisheye (k1, k2 = ``IMMERSIVE_K``, about half the README camera's)
  with twice the rig's focal length, because the loader undistorts to focal x 0.5
  (``ftgspp.data.immersive``). The fisheye must cover the pinhole, so the rig is wide (default
  ``hfov_deg`` 150; narrower rigs are refused). Pixels whose distorted angle r / f exceeds
  pi/2 are black: that is where ``cv2.fisheye.undistortPoints`` stops (it clamps beyond), and
  the lens's image circle here; undistortion never samples them. Cameras are named
  ``camera_0001`` (the rig's ``cam00``, the held-out middle view), ``camera_0002`` ...; videos
  ``camera_NNNN.mp4`` and ``models.json`` as the publisher writes them.
- ``enerf_outdoor``: OpenCV radial-tangential distortion ``ENERF_OUTDOOR_D`` (barrel, so the
  loader's same-K undistortion has no black border); EasyMocap-style ``intri.yml`` /
  ``extri.yml`` as ENeRF-Outdoor ships them (``names``, ``K_``, ``dist_``, ``R_``, ``Rot_``,
  ``T_``; no image size), cameras ``00``, ``01`` ... (``00`` held out), JPEG frames in
  ``images/<cam>/<frame:06d>.jpg``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ftgspp.data.immersive import FOCAL_SCALE, MODELS_FILE
from ftgspp.data.scene import Camera
from ftgspp.errors import InputError

LENS_LAYOUTS = ("immersive", "enerf_outdoor")
LAYOUT_DEFAULTS = {"immersive": {"hfov_deg": 150.0}}  # SynthConfig values unless overridden
IMMERSIVE_K = (0.05, -0.01)  # the README's camera_0001 has (0.097, -0.017): a wider circle here
CIRCLE = math.pi / 2  # image circle: distorted angle r / f (cv2.fisheye.undistortPoints' range)
ENERF_OUTDOOR_D = (-0.25, 0.07, 8e-4, -6e-4, 0.0)  # k1, k2, p1, p2, k3: a wide-angle barrel
JPEG_QUALITY = 98
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
# undistortion samples stay this far inside the valid image: the loaders' interpolation support
_MARGIN_PX = {"fisheye": 2.0, "opencv": 1.0}  # immersive.py: bicubic; easyvolcap.py: bilinear


@dataclass(frozen=True)
class Lens:
    """A distorting lens in front of rig camera ``camera`` (its pose, size and undistorted K)."""

    model: str  # "fisheye" (cv2.fisheye) | "opencv" (radial-tangential, cv2.undistortPoints)
    camera: Camera
    K: np.ndarray  # [3, 3] intrinsics of the distorted image
    D: np.ndarray  # [4] fisheye or [5] k1, k2, p1, p2, k3

    def normalized(self, pixels: np.ndarray) -> np.ndarray:
        """Undistorted normalized coordinates ``[N, 2]`` (x/z, y/z) of distorted pixels ``[N, 2]``."""
        pts = pixels.reshape(-1, 1, 2).astype(np.float64)
        if self.model == "fisheye":
            out = cv2.fisheye.undistortPoints(pts, self.K, self.D, criteria=_CRITERIA)
        else:
            out = cv2.undistortPoints(pts, self.K, self.D, criteria=_CRITERIA)
        return out.reshape(-1, 2)

    def circle(self, pixels: np.ndarray) -> np.ndarray:
        """``[N]`` bool: inside the image circle (always true for the radial-tangential lens)."""
        if self.model != "fisheye":
            return np.ones(len(pixels), bool)
        return _fisheye_radius(self, pixels) < CIRCLE

    def rays(self, supersample: int = 1) -> np.ndarray:
        """World ray directions with unit camera-z, ``[H*s, W*s, 3]`` (sub-pixels as ``pixel_rays``)."""
        s, cam = supersample, self.camera
        x = (np.arange(cam.width * s) + 0.5) / s - 0.5
        y = (np.arange(cam.height * s) + 0.5) / s - 0.5
        pix = np.stack(np.meshgrid(x, y), -1).reshape(-1, 2)
        if self.model == "fisheye":  # beyond the image circle: rays at its edge (those pixels end up black)
            r = _fisheye_radius(self, pix)
            centre = self.K[:2, 2]
            pix = centre + (pix - centre) * np.minimum(1.0, (CIRCLE - 1e-6) / np.maximum(r, 1e-12))[:, None]
        xy = self.normalized(pix)
        d_cam = np.concatenate([xy, np.ones((len(xy), 1))], 1)
        return (d_cam @ cam.R).reshape(cam.height * s, cam.width * s, 3)

    def mask(self, frames: np.ndarray) -> np.ndarray:
        """``frames [F, H, W, 3]`` with pixels outside the image circle set to 0."""
        cam = self.camera
        pix = np.stack(np.meshgrid(np.arange(cam.width), np.arange(cam.height)), -1).reshape(-1, 2)
        out = frames.copy()
        out[:, ~self.circle(pix).reshape(cam.height, cam.width)] = 0
        return out

    def undistort_maps(self) -> np.ndarray:
        """float32 ``[2, H, W]``: where the loader's undistortion samples each pinhole pixel."""
        cam = self.camera
        size = (cam.width, cam.height)
        if self.model == "fisheye":
            maps = cv2.fisheye.initUndistortRectifyMap(self.K, self.D, np.eye(3), cam.K, size, cv2.CV_32FC1)
        else:
            maps = cv2.initUndistortRectifyMap(self.K, self.D, None, cam.K, size, cv2.CV_32FC1)
        return np.stack(maps)

    def check_coverage(self) -> None:
        """InputError unless every undistorted pixel samples valid distorted pixels."""
        mx, my = self.undistort_maps()
        cam, m = self.camera, _MARGIN_PX[self.model]
        ok = (mx >= m - 1) & (mx <= cam.width - m) & (my >= m - 1) & (my <= cam.height - m)
        if self.model == "fisheye":
            limit = CIRCLE - m / self.K[0, 0]
            ok &= _fisheye_radius(self, np.stack([mx.ravel(), my.ravel()], 1)).reshape(mx.shape) < limit
        if not ok.all():
            raise InputError("synth hfov_deg", f"a {math.degrees(2 * math.atan(cam.width / 2 / cam.K[0, 0])):.0f} "
                             f"degree rig is too narrow for the {self.model} lens: its undistorted image would leave "
                             f"the distorted one ({100 * (1 - ok.mean()):.1f}% of pixels); widen hfov_deg")


def _fisheye_radius(lens: Lens, pixels: np.ndarray) -> np.ndarray:
    """Normalized fisheye radius r_d / f of pixels ``[N, 2]``."""
    return np.linalg.norm((pixels - lens.K[:2, 2]) / np.diag(lens.K)[:2], axis=1)


def make_lenses(layout: str, cams: list[Camera]) -> list[Lens]:
    """The lenses of ``layout`` in front of the rig ``cams``, renamed as the layout names cameras
    (``cam07`` -> ``camera_0008`` / ``07``); InputError if a lens cannot cover its camera."""
    if layout == "immersive":
        cams = [replace(c, name=f"camera_{int(c.name[3:]) + 1:04d}") for c in cams]
    else:
        cams = [replace(c, name=c.name[3:]) for c in cams]
    return [make_lens(layout, c) for c in cams]


def make_lens(layout: str, cam: Camera) -> Lens:
    """The lens of ``layout`` in front of pinhole ``cam``; InputError if it cannot cover ``cam``."""
    if layout == "immersive":
        K = cam.K.copy()
        K[0, 0] /= FOCAL_SCALE
        K[1, 1] /= FOCAL_SCALE
        lens = Lens("fisheye", cam, K, np.array([*IMMERSIVE_K, 0.0, 0.0]))
    else:
        lens = Lens("opencv", cam, cam.K.copy(), np.array(ENERF_OUTDOOR_D))
    lens.check_coverage()
    return lens


def write_layout_frames(out: Path, layout: str, cam: Camera, frames: np.ndarray,
                        write_video: Callable[[Path, np.ndarray], None]) -> None:
    """The distorted frames ``[F, H, W, 3]`` of one camera: a video (immersive) or JPEGs (enerf_outdoor)."""
    if layout == "immersive":
        write_video(out / f"{cam.name}.mp4", frames)
        return
    folder = out / "images" / cam.name
    folder.mkdir(parents=True, exist_ok=True)
    for f, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"{f:06d}.jpg"), frame[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])


def write_layout_cameras(out: Path, layout: str, lenses: list[Lens]) -> None:
    """``models.json`` (immersive) or ``intri.yml`` + ``extri.yml`` (enerf_outdoor) for ``lenses``."""
    if layout == "immersive":
        models = []
        for lens in lenses:
            cam = lens.camera
            models.append(dict(
                name=cam.name, position=cam.center.tolist(), orientation=cv2.Rodrigues(cam.R)[0].ravel().tolist(),
                focal_length=float(lens.K[0, 0]), pixel_aspect_ratio=1.0, principal_point=lens.K[:2, 2].tolist(),
                width=float(cam.width), height=float(cam.height),
                radial_distortion=[float(lens.D[0]), float(lens.D[1]), 0.0], projection_type="fisheye"))
        (out / MODELS_FILE).write_text(json.dumps(models, indent=1) + "\n")
        return
    intri = cv2.FileStorage(str(out / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(out / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    for fs in (intri, extri):
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for lens in lenses:
            fs.write("", lens.camera.name)
        fs.endWriteStruct()
    for lens in lenses:
        cam = lens.camera
        intri.write(f"K_{cam.name}", lens.K)
        intri.write(f"dist_{cam.name}", lens.D.reshape(1, -1))
        extri.write(f"R_{cam.name}", cv2.Rodrigues(cam.R)[0])
        extri.write(f"Rot_{cam.name}", cam.R)
        extri.write(f"T_{cam.name}", cam.T.reshape(3, 1))
    intri.release()
    extri.release()


def lens_metadata(lens: Lens) -> dict:
    """What ``gt/scene.json`` records about a camera's lens."""
    return dict(model=lens.model, K=lens.K.tolist(), D=lens.D.tolist(),
                image_circle="black where r / f > pi/2" if lens.model == "fisheye" else None,
                gt="ground truth is for the undistorted (pinhole) camera the loader returns")
