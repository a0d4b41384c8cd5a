"""Synthetic scenes through a lens (``ftgspp synth --layout immersive|enerf_outdoor``).

Each lens scene is compared with the same content written in the plain DyNeRF layout (same
seed, same rig): its files are what the dataset's users expect, its frames undistort back onto
the plain frames, and training with identical settings lands in the plain layout's quality band.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ftgspp.config import DataConfig, TrainConfig
from ftgspp.data.immersive import read_models
from ftgspp.data.load import detect_format, load_scene
from ftgspp.data.synthetic.build import generate, main
from ftgspp.data.synthetic.layouts import ENERF_OUTDOOR_D, LENS_LAYOUTS, make_lens
from ftgspp.data.synthetic.rig import make_rig
from ftgspp.errors import InputError
from ftgspp.evaluate import evaluate
from ftgspp.methods.freetime import FreeTimeGaussians
from ftgspp.trainer import train

SMALL = dict(width=64, height=48, n_frames=6, n_cameras=6)
HFOV = {"immersive": 150.0, "enerf_outdoor": 55.0}  # the layout default / SynthConfig's default
PSNR_TOL_DB = 1.5  # a lens layout may not train worse than the plain one by more than this
# ... nor better by more than this (a sanity bound: black frames would fit easily). Undistorted
# frames are smoother (interpolation; ENeRF-Outdoor's JPEGs), which 120 iterations fit better:
# seeds 0-2 gave immersive +0.7..+3.3 dB, enerf_outdoor +1.7..+2.4 dB (JPEG alone about +0.9).
# Frames undistorted with a wrong lens (focal x 0.6, or k1 = k2 = 0) are 21-23 dB from the plain
# frames instead of 29-30 dB: test_frames_undistort_onto_the_plain_layouts_frames catches them.
PSNR_ABOVE_DB = 5.0


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("lens")
    out = {}
    for layout in LENS_LAYOUTS:
        out[layout] = generate(root / layout, layout=layout, seed=0, **SMALL)
        out[f"{layout}_plain"] = generate(root / f"{layout}_plain", seed=0, hfov_deg=HFOV[layout], **SMALL)
    return out


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2) / 255.0**2
    return float(10 * np.log10(1.0 / mse))


def _raw_frames(scene: Path, layout: str, name: str) -> np.ndarray:
    if layout == "enerf_outdoor":
        files = sorted((scene / "images" / name).glob("*.jpg"))
        return np.stack([cv2.imread(str(f))[..., ::-1] for f in files])
    cap, frames = cv2.VideoCapture(str(scene / f"{name}.mp4")), []
    while (frame := cap.read())[0]:
        frames.append(frame[1][..., ::-1])
    return np.stack(frames)


@pytest.mark.parametrize("layout", LENS_LAYOUTS)
def test_lens_rays_project_back_onto_their_pixels(layout):
    """Rays from the inverse lens model land on their own (sub)pixels through OpenCV's forward model."""
    cam = make_rig(2, 64, 48, HFOV[layout], 50.0, 4.4, np.zeros(3), 0.0)[1]
    lens = make_lens(layout, cam)
    rays = lens.rays(2).reshape(-1, 3)  # world directions from the camera centre
    x = (np.arange(64 * 2) + 0.5) / 2 - 0.5
    y = (np.arange(48 * 2) + 0.5) / 2 - 0.5
    pix = np.stack(np.meshgrid(x, y), -1).reshape(-1, 2)
    inside = lens.circle(pix)
    points = (cam.center + rays)[inside].reshape(-1, 1, 3)
    rvec = cv2.Rodrigues(cam.R)[0]
    if layout == "immersive":
        back = cv2.fisheye.projectPoints(points, rvec, cam.T, lens.K, lens.D)[0]
        assert 0.05 < 1 - inside.mean() < 0.5  # the corners lie outside the image circle
    else:
        back = cv2.projectPoints(points, rvec, cam.T, lens.K, lens.D)[0]
        assert inside.all()
    assert np.abs(back.reshape(-1, 2) - pix[inside]).max() < 1e-6


def test_lens_scene_has_the_same_bytes_from_two_worker_processes(scenes, tmp_path):
    ref = scenes["immersive"]  # rendered in this process (a small scene)
    again = generate(tmp_path / "two", layout="immersive", seed=0, workers=2, **SMALL)
    files = sorted(p.relative_to(ref) for p in ref.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        assert (ref / rel).read_bytes() == (again / rel).read_bytes(), rel


def test_immersive_files_are_the_publishers(scenes):
    scene = scenes["immersive"]
    models = json.loads((scene / "models.json").read_text())
    assert [m["name"] for m in models] == [f"camera_{i:04d}" for i in range(1, 7)]
    assert {m["projection_type"] for m in models} == {"fisheye"} and all(len(m["orientation"]) == 3 for m in models)
    gt = json.loads((scene / "gt" / "scene.json").read_text())
    assert gt["test_cameras"] == ["camera_0001"]
    for m, cam in zip(read_models(scene / "models.json"), gt["cameras"]):
        assert m.name == cam["name"] and m.K[0, 0] == pytest.approx(2 * cam["K"][0][0])  # undistorts to x 0.5
    raw = _raw_frames(scene, "immersive", "camera_0001")
    assert raw.shape == (6, 48, 64, 3) and raw[:, 0, 0].max() == 0 and raw[:, 24, 32].min() > 0  # image circle


def test_enerf_outdoor_files_are_easymocap_style(scenes):
    scene = scenes["enerf_outdoor"]
    intri = cv2.FileStorage(str(scene / "intri.yml"), cv2.FILE_STORAGE_READ)
    extri = cv2.FileStorage(str(scene / "extri.yml"), cv2.FILE_STORAGE_READ)
    assert [intri.getNode("names").at(i).string() for i in range(6)] == [f"{i:02d}" for i in range(6)]
    np.testing.assert_allclose(intri.getNode("dist_00").mat().ravel(), ENERF_OUTDOOR_D)
    assert intri.getNode("H_00").empty() and intri.getNode("D_00").empty()
    assert not extri.getNode("R_00").empty() and not extri.getNode("Rot_00").empty()
    assert (scene / "images" / "05" / "000005.jpg").is_file() and detect_format(scene) == "easyvolcap"


@pytest.mark.parametrize("layout", LENS_LAYOUTS)
def test_frames_undistort_onto_the_plain_layouts_frames(scenes, layout):
    lens, plain = (load_scene(DataConfig(path=str(scenes[k]))) for k in (layout, f"{layout}_plain"))
    gt_cameras = json.loads((scenes[layout] / "gt" / "scene.json").read_text())["cameras"]
    for c, (got, want) in enumerate(zip(lens.cameras, plain.cameras)):  # the loader's pinhole = the rig camera
        for key in ("K", "R", "T"):
            np.testing.assert_allclose(getattr(got, key), getattr(want, key), atol=1e-9)
            np.testing.assert_allclose(getattr(got, key), gt_cameras[c][key], atol=1e-9)  # gt/ is for it
        undistorted = _psnr(lens.frames(c), plain.frames(c))
        raw = _psnr(_raw_frames(scenes[layout], layout, got.name), plain.frames(c))
        assert undistorted > 25.0 and undistorted > raw + 3.0, (got.name, undistorted, raw)
    depth = np.load(scenes[layout] / "gt" / "depth" / f"{lens.cameras[0].name}.npy")
    assert depth.shape == (6, 48, 64)


def test_a_rig_too_narrow_for_the_fisheye_is_refused(tmp_path, capsys):
    with pytest.raises(InputError, match="hfov_deg.*too narrow"):
        generate(tmp_path / "a", layout="immersive", hfov_deg=100.0, **SMALL)
    assert main(["--out", str(tmp_path / "b"), "--layout", "immersive", "--hfov", "55", "--frames", "1"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def _train_cfg(path: Path, out_dir: Path) -> TrainConfig:
    """The trainer tests' smoke settings (tests/test_trainer.py), without LPIPS and diagnostics."""
    cfg = TrainConfig()
    cfg.data.path, cfg.out_dir = str(path), str(out_dir)
    cfg.iterations, cfg.budget, cfg.backend, cfg.progress = 120, 400, "cpu", False
    cfg.log_every, cfg.checkpoint_every, cfg.sh_degree_interval = 5, 10_000, 10
    cfg.init.keyframe_stride = 3
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter, cfg.strategy.refine_stop_iter = 10, 5, 35
    cfg.eval_lpips, cfg.diagnostics = [], False
    return cfg


@pytest.mark.parametrize("layout", LENS_LAYOUTS)
def test_training_reaches_the_plain_layouts_quality_band(scenes, layout, tmp_path, capsys):
    plain_scene = load_scene(DataConfig(path=str(scenes[f"{layout}_plain"])))
    plain = train(_train_cfg(scenes[f"{layout}_plain"], tmp_path / "plain"), plain_scene).metrics["psnr"]
    cfg = _train_cfg(scenes[layout], tmp_path / "lens")
    result = train(cfg, load_scene(DataConfig(path=str(scenes[layout]))))
    assert result.status == "FINISHED"
    model = FreeTimeGaussians(torch.load(tmp_path / "lens" / "gaussians.pt", weights_only=True), cfg.model)
    # the lens-trained model in the same test camera, against the plain layout's (true) frames
    cross = evaluate(model, plain_scene, cfg, tmp_path / "cross")[0]["psnr"]
    own = result.metrics["psnr"]
    with capsys.disabled():
        print(f"\n{layout}: PSNR {own:.2f} dB (vs plain-layout frames {cross:.2f}), plain dynerf layout {plain:.2f}")
    assert plain - PSNR_TOL_DB <= own <= plain + PSNR_ABOVE_DB
    assert cross >= plain - PSNR_TOL_DB
