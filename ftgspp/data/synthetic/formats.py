"""The on-disk files of a synthetic scene: videos, camera files and ground-truth JSON (``ftgspp synth``).

DyNeRF's ``camNN.mp4`` and ``poses_bounds.npy`` rows, EasyVolcap's ``intri.yml`` / ``extri.yml``,
and ``gt/trajectories.json`` / ``gt/objects.json``.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.data.synthetic.geometry import SceneContent
from ftgspp.data.synthetic.presets import CODECS, SynthConfig


def write_video(path: Path, frames: np.ndarray, fps: float, codec: str = "ffv1") -> None:
    """Encode uint8 RGB frames ``[F, H, W, 3]`` as an mp4 with OpenCV (``codec`` in ``CODECS``)."""
    F, H, W, _ = frames.shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*CODECS[codec]), fps, (W, H))
    if not writer.isOpened():
        raise RuntimeError(f"{path}: OpenCV cannot open a '{codec}' video writer")
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[..., ::-1]))
    writer.release()


def poses_bounds_row(cam: Camera, near: float, far: float) -> np.ndarray:
    """One LLFF/DyNeRF ``poses_bounds`` row ``[17]``: 3x5 [down, right, back, centre, hwf], near, far."""
    c2w = cam.R.T  # OpenCV camera-to-world axes as columns: [x right, y down, z forward]
    pose = np.stack([c2w[:, 1], c2w[:, 0], -c2w[:, 2], cam.center,
                     [cam.height, cam.width, cam.K[0, 0]]], axis=1)  # [3, 5]
    return np.concatenate([pose.reshape(-1), [near, far]])


def write_easyvolcap_cameras(out: Path, cams: list[Camera]) -> None:
    """``intri.yml`` and ``extri.yml`` as OpenCV FileStorage YAML."""
    intri = cv2.FileStorage(str(out / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(out / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    for fs in (intri, extri):
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for cam in cams:
            fs.write("", cam.name)
        fs.endWriteStruct()
    for cam in cams:
        intri.write(f"K_{cam.name}", cam.K)
        intri.write(f"D_{cam.name}", np.zeros((1, 5)))
        intri.write(f"H_{cam.name}", int(cam.height))
        intri.write(f"W_{cam.name}", int(cam.width))
        extri.write(f"R_{cam.name}", cv2.Rodrigues(cam.R)[0])
        extri.write(f"Rot_{cam.name}", cam.R)
        extri.write(f"T_{cam.name}", cam.T.reshape(3, 1))
    intri.release()
    extri.release()


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=1) + "\n")


def trajectories_json(content: SceneContent, cfg: SynthConfig) -> dict:
    times = np.arange(cfg.n_frames) / cfg.fps
    objs = []
    for o in content.objects:
        objs.append(dict(
            label=o.label, name=o.name, kind=o.path.kind, shape="sphere", radius=o.radius,
            angular_velocity=o.angular_velocity().tolist(),
            path={k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(o.path).items()},
            position=[o.path.position(t).tolist() for t in times],
            velocity=[o.path.velocity(t).tolist() for t in times],
        ))
    return dict(units="world units; velocity in units/s; angular_velocity in rad/s (world axes)",
                fps=cfg.fps, times=times.tolist(), objects=objs)


def objects_json(content: SceneContent, cfg: SynthConfig, pixels: dict[str, dict[int, list[int]]]) -> dict:
    """``gt/objects.json``: every object's id, role and existence window, and its visible pixels
    per camera and frame (0 while it is absent or hidden behind something)."""
    times = np.arange(cfg.n_frames) / cfg.fps
    objs = []
    for o in content.objects:
        a, b = o.visible
        objs.append(dict(label=o.label, name=o.name, role=o.role,
                         exists=[None if not np.isfinite(a) else a, None if not np.isfinite(b) else b],
                         present=[o.present(t) for t in times],
                         visible_pixels={cam: counts[o.label] for cam, counts in pixels.items()}))
    return dict(note="exists: [appears, disappears) in seconds, null = the whole clip; visible_pixels per "
                     "camera and frame from gt/objects", fps=cfg.fps, objects=objs)
