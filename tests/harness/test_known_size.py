"""The known-size scene: K Gaussians that FreeTimeGS redraws exactly, loaded like any DyNeRF scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from ftgspp.config import DataConfig, ModelConfig
from ftgspp.data.load import load_scene
from ftgspp.errors import InputError
from ftgspp.methods.freetime import SH_C0, FreeTimeGaussians
from ftgspp.view import render_view
from harness.run import known_size
from harness.run.scenes import ensure_scene
from harness.spec.study_schema import StudyScene
from harness.spec.synth import validate_synth

TINY = dict(k=40, n_cameras=4, n_frames=4, width=64, height=48, sigma_px=2.0)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return known_size.generate(tmp_path_factory.mktemp("ks") / "scene", seed=3, **TINY)


def _truth_as_model(npz: dict, t_mid: float) -> FreeTimeGaussians:
    """A FreeTimeGS model with one Gaussian per true one: the same centre at t_mid, velocity,
    scale, rotation, opacity and colour, and a lifetime far longer than the clip."""
    k = len(npz["means"])
    f = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    o = f(npz["opacities"])
    params = {
        "means": f(npz["means"]), "times": torch.full((k,), t_mid), "durations": torch.full((k,), 10.0),
        "velocities": f(npz["velocities"]), "scales": torch.log(f(npz["scales"])), "quats": f(npz["quats"]),
        "opacities": torch.log(o / (1 - o)), "sh0": ((f(npz["colors"]) - 0.5) / SH_C0)[:, None, :],
        "shN": torch.zeros(k, 0, 3), "gates": torch.zeros(k),
    }
    return FreeTimeGaussians(params, ModelConfig(sh_degree=0, max_duration=None, gate=False))


def test_the_scene_is_k_gaussians_freetimegs_redraws(scene_dir: Path) -> None:
    meta = json.loads((scene_dir / "known_size.json").read_text())
    assert meta["k"] == 40 and meta["moving"] == 10  # a quarter moves
    npz = dict(np.load(scene_dir / "known_size.npz"))
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    model = _truth_as_model(npz, float(npz["t_mid"]))
    worst = 0.0
    for cam_idx in range(len(scene.cameras)):
        for frame in (0, scene.n_frames - 1):
            gt = torch.from_numpy(scene.image(cam_idx, frame))  # [H, W, 3] in [0, 1]
            with torch.no_grad():
                out, _ = render_view(model, scene.cameras[cam_idx], float(scene.times[frame]), 0, torch.zeros(3), "cpu")
            worst = max(worst, float((out.image.clamp(0, 1) - gt).abs().max()))
    assert worst <= 1.0 / 255 + 1e-4  # only the 8-bit rounding of the lossless video
    assert scene.cameras[scene.test_ids[0]].name == "cam00"


def test_moving_gaussians_move_and_the_rest_stay(scene_dir: Path) -> None:
    npz = np.load(scene_dir / "known_size.npz")
    speed = np.linalg.norm(npz["velocities"], axis=1)
    assert np.allclose(speed[npz["moving"] > 0], 0.5) and np.all(speed[npz["moving"] == 0] == 0)


def test_a_study_scene_names_it_as_a_preset(tmp_path: Path) -> None:
    scene = StudyScene("ks", {"preset": known_size.PRESET, "seed": 0, "layout": "dynerf", **TINY},
                       synth_dir=str(tmp_path / "ks"))
    validate_synth(scene)
    assert ensure_scene(scene, echo=lambda _: None)
    assert (tmp_path / "ks" / "known_size.json").is_file()
    assert not ensure_scene(scene, echo=lambda _: None)  # the same arguments: reused
    with pytest.raises(InputError, match="unknown argument"):
        validate_synth(StudyScene("bad", {"preset": known_size.PRESET, "seed": 0, "layout": "dynerf", "blobs": 3}))


def test_the_command_line_writes_it_and_refuses_bad_arguments(tmp_path: Path) -> None:
    args = ["--out", str(tmp_path / "cli"), "--seed", "1"] + [f"--set={k}={v}" for k, v in TINY.items()]
    assert known_size.main(args) == 0 and (tmp_path / "cli" / "known_size.json").is_file()
    assert known_size.main(["--out", str(tmp_path / "bad"), "--set=blobs=3"]) == 2
