"""The sphere scene writer (harness/run/spheres.py), checked against computations of its own: the
cameras ftgspp's DyNeRF loader reads back are the ones written, a pixel's true depth is the
ray–sphere intersection worked out here by closest approach (the writer solves a quadratic), the
missing camera is missing, and a study file may name the scene as a preset (one error line when an
argument is bad)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.errors import InputError
from harness.run import spheres
from harness.run.scenes import ensure_scene
from harness.spec.study_schema import StudyScene
from harness.spec.synth import validate_synth

TINY = dict(n_cameras=5, missing=3, n_frames=3, width=40, height=30, supersample=1, color_gain=0.05)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return spheres.generate(tmp_path_factory.mktemp("sph") / "scene", seed=4, **TINY)


def _hit_distance(origin: np.ndarray, unit: np.ndarray, centre: np.ndarray, radius: float, inside: bool) -> float:
    """Distance along the unit ray to the sphere, by closest approach (inf if it misses)."""
    along = float(unit @ (centre - origin))
    miss2 = float(np.sum((centre - origin - along * unit) ** 2))
    if miss2 > radius**2:
        return np.inf
    half = np.sqrt(radius**2 - miss2)
    t = along + half if inside else along - half
    return t if t > 0 else np.inf


def test_the_loader_reads_back_the_cameras_written_without_the_missing_one(scene_dir: Path) -> None:
    meta = json.loads((scene_dir / "spheres.json").read_text())
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    names = [c.name for c in scene.cameras]
    assert names == ["cam00", "cam01", "cam02", "cam04"] and "cam03" not in meta["cameras"]
    assert scene.cameras[scene.test_ids[0]].name == "cam00" and scene.n_frames == TINY["n_frames"]
    for cam in scene.cameras:
        w = meta["cameras"][cam.name]
        np.testing.assert_allclose(cam.R, w["R"], atol=1e-12)
        np.testing.assert_allclose(cam.T, w["T"], atol=1e-12)
        np.testing.assert_allclose(cam.K, w["K"], atol=1e-12)
        assert (cam.width, cam.height) == (TINY["width"], TINY["height"])
    # cam00 in the middle of the arc: the others lie on both sides of it
    x = [float(c.center[0]) for c in scene.cameras]
    assert min(x) < x[0] < max(x)


def test_true_depth_is_the_ray_sphere_intersection(scene_dir: Path) -> None:
    meta = json.loads((scene_dir / "spheres.json").read_text())
    s = {k: np.asarray(v) for k, v in meta["spheres"].items()}
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    checked = 0
    for cam in scene.cameras:
        depth = np.load(scene_dir / "gt" / "depth" / f"{cam.name}.npy")
        for f in range(scene.n_frames):
            t = f / scene.fps
            centres = s["centres"] + s["velocities"] * t
            for y, x in ((3, 4), (15, 20), (25, 33), (10, 30)):
                ray = cam.R.T @ np.linalg.solve(cam.K, [x, y, 1.0])  # world direction, z-component 1 in the camera
                unit = ray / np.linalg.norm(ray)
                dist = min([_hit_distance(cam.center, unit, c, r, False) for c, r in zip(centres, s["radii"])]
                           + [_hit_distance(cam.center, unit, np.zeros(3), meta["backdrop_radius"], True)])
                z = dist / np.linalg.norm(ray)  # distance along the ray -> camera z-depth
                assert depth[f, y, x] == pytest.approx(z, rel=1e-5)
                checked += 1
            # a pixel on each visible sphere's projected centre sees that sphere (or one in front of it)
            for c, r in zip(centres, s["radii"]):
                uvw = cam.K @ (cam.R @ c + cam.T)
                x, y = int(round(uvw[0] / uvw[2])), int(round(uvw[1] / uvw[2]))
                if 0 <= x < cam.width and 0 <= y < cam.height:
                    assert depth[f, y, x] <= uvw[2] + 1e-6  # at most as far as the sphere's centre
    assert checked == 4 * 3 * 4


def test_moving_spheres_are_labelled_with_their_velocity(scene_dir: Path) -> None:
    meta = json.loads((scene_dir / "spheres.json").read_text())
    vel = np.asarray(meta["spheres"]["velocities"])
    objects = np.load(scene_dir / "gt" / "objects" / "cam00.npy")
    flow = np.load(scene_dir / "gt" / "flow3d" / "cam00.npy")
    assert objects.dtype == np.uint8 and objects.max() >= 1
    for label in np.unique(objects[objects > 0]):
        seen = objects == label
        np.testing.assert_allclose(flow[seen], np.broadcast_to(vel[label - 1], (int(seen.sum()), 3)), atol=1e-6)
    assert np.all(flow[objects == 0] == 0)


def test_a_study_scene_names_it_as_a_preset_and_a_bad_argument_is_one_line(tmp_path: Path) -> None:
    scene = StudyScene("sph", {"preset": spheres.PRESET, "seed": 0, "layout": "dynerf", **TINY},
                       synth_dir=str(tmp_path / "sph"))
    validate_synth(scene)
    assert ensure_scene(scene, echo=lambda _: None)
    assert (tmp_path / "sph" / "spheres.json").is_file()
    assert not ensure_scene(scene, echo=lambda _: None)  # the same arguments: reused
    for bad, match in (({"blobs": 3}, "unknown argument"), ({"missing": 0}, "missing"), ({"width": 31}, "width"),
                       ({"n_cameras": "8"}, "n_cameras")):
        with pytest.raises(InputError, match=match) as err:
            validate_synth(StudyScene("bad", {"preset": spheres.PRESET, "seed": 0, "layout": "dynerf", **bad}))
        assert "\n" not in str(err.value) and str(err.value).startswith("scene 'bad' synth")
    assert spheres.main(["--out", str(tmp_path / "bad"), "--set=missing=9"]) == 2


def test_a_runs_reproduce_command_writes_the_same_scene(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the `command` column of runs.csv: `python -m harness.run.spheres ...` for this preset (an
    # `ftgspp synth` command would fail on it); run its first part and compare with the study's scene
    import os
    import shlex
    import subprocess
    import sys

    from harness.spec.runs import RunSpec, standalone_command

    monkeypatch.chdir(tmp_path)
    scene = StudyScene("val", synth={"preset": "spheres", "seed": 4, "layout": "dynerf", **TINY},
                       synth_dir="data/synth/val")
    command = standalone_command(RunSpec("s", "quick", "sift", scene, 0, ("profile=quick",)))
    write, train = command.split(" && ")
    assert write.startswith("python -m harness.run.spheres --out data/synth/val --seed 4") and "ftgspp synth" not in command
    assert train.startswith("ftgspp train profile=quick")
    repo = str(Path(__file__).resolve().parents[2])
    subprocess.run([sys.executable, *shlex.split(write)[1:]], check=True, cwd=tmp_path, env={**os.environ, "PYTHONPATH": repo})
    study = spheres.generate(tmp_path / "study", seed=4, **TINY)  # what the study's writer makes of the same arguments
    files = sorted(p.relative_to(study) for p in study.rglob("*.npy"))
    assert files
    for f in files:
        np.testing.assert_array_equal(np.load(tmp_path / "data/synth/val" / f), np.load(study / f))
