"""Scene loaders on bad input: every broken file or option is one ``InputError`` naming it
(DyNeRF, EasyVolcap, and Immersive's ``models.json``: one line naming the field, exit 2 from the CLI).

Scenes are the tiny folders of ``fixtures.py``, broken one way at a time: before loading
(wrong shapes, NaN, corrupt files, missing entries, bad options) and after loading, while
frames are decoded (files removed, truncated or resized). The message is one line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.errors import InputError

try:  # tests/ importable as a package
    from tests.data import fixtures as fx
except ImportError:  # pytest's default "prepend" import mode puts this folder on sys.path
    import fixtures as fx  # type: ignore[no-redef]


def _poses(root: Path) -> np.ndarray:
    return np.load(root / "poses_bounds.npy")


def _corrupt_bytes(path: Path) -> None:
    path.write_bytes(b"this is not what it claims to be" * 8)


DYNERF_BAD = {
    "poses wrong shape": (lambda r: np.save(r / "poses_bounds.npy", _poses(r)[:, :15]), {}, "poses_bounds.npy"),
    "poses NaN": (
        lambda r: np.save(r / "poses_bounds.npy", np.where(np.eye(4, 17, 3) > 0, np.nan, _poses(r))),
        {},
        "poses_bounds.npy",
    ),
    "poses Inf": (
        lambda r: np.save(r / "poses_bounds.npy", np.where(np.eye(4, 17, 16) > 0, np.inf, _poses(r))),
        {},
        "poses_bounds.npy",
    ),
    "poses not npy": (lambda r: _corrupt_bytes(r / "poses_bounds.npy"), {},
                      "poses_bounds.npy: not a NumPy .npy file \\(it starts with b'this is not what'"),
    "poses a text file": (lambda r: np.savetxt(r / "poses_bounds.npy", _poses(r)), {},
                          "poses_bounds.npy: not a NumPy .npy file \\(it starts with b'-?[0-9]"),
    "poses empty": (lambda r: (r / "poses_bounds.npy").write_bytes(b""), {}, "not a NumPy .npy file \\(it is empty"),
    "poses not a rotation": (
        lambda r: np.save(r / "poses_bounds.npy", _poses(r) * np.r_[[2.0] * 3, [1.0] * 14]),
        {},
        "poses_bounds.npy",
    ),
    "more rows than videos": (
        lambda r: np.save(r / "poses_bounds.npy", np.vstack([_poses(r), _poses(r)[:1]])),
        {},
        "poses_bounds.npy.*5 camera rows.*4 videos",
    ),
    "fewer rows than videos": (
        lambda r: np.save(r / "poses_bounds.npy", _poses(r)[:3]),
        {},
        "poses_bounds.npy.*3 camera rows.*4 videos",
    ),
    "corrupt video": (lambda r: _corrupt_bytes(r / "cam02.mp4"), {}, "cam02.mp4"),
    "short video": (
        lambda r: fx.write_video(r / "cam01.mp4", [fx.render_frame(fx.ring_cameras(["x"])[0], 0.0)] * 3, 30.0),
        dict(frame_end=5),
        "cam01.mp4.*3 frames.*needs 5",
    ),
    "range past every video": (lambda r: None, dict(frame_start=6), "cam00.mp4.*6 frames"),
    "video of another aspect": (
        lambda r: fx.write_video(r / "cam03.mp4", [np.zeros((24, 40, 3), np.uint8)] * 6, 30.0),
        {},
        "cam03.mp4.*40x24",
    ),
    "empty frame range": (lambda r: None, dict(frame_start=3, frame_end=3), "data.frame_end.*empty"),
    "negative frame start": (lambda r: None, dict(frame_start=-1), "data.frame_start"),
    "unknown drop camera": (lambda r: None, dict(drop_cameras=["cam13"]), "data.drop_cameras.*cam13"),
    "every camera dropped": (
        lambda r: None, dict(drop_cameras=["cam00", "cam01", "cam02", "cam03"]), "data.drop_cameras.*every"
    ),
    "unknown test camera": (lambda r: None, dict(test_cameras=["cam13"]), "data.test_cameras.*cam13"),
    "downsample below 1": (lambda r: None, dict(downsample=0.5), "data.downsample"),
    "unknown format": (lambda r: None, dict(format="llff"), "data.format.*llff"),
    "missing folder": (lambda r: None, dict(path="/nonexistent/scene"), "/nonexistent/scene.*not found"),
}


@pytest.mark.parametrize("case", list(DYNERF_BAD))
def test_dynerf_bad_input_raises_input_error(tmp_path, case):
    mutate, options, pattern = DYNERF_BAD[case]
    root = fx.write_dynerf(tmp_path / "s", n_frames=6)
    mutate(root)
    with pytest.raises(InputError, match=pattern) as err:
        load_scene(DataConfig(**{"path": str(root), **options}))
    assert "\n" not in str(err.value)


def _drop_line(path: Path, prefix: str) -> None:
    """Remove the yml entry starting with ``prefix`` (and its indented continuation lines)."""
    out, skipping = [], False
    for line in path.read_text().splitlines(keepends=True):
        if line.startswith(prefix):
            skipping = True
            continue
        if skipping and line.startswith("   "):
            continue
        skipping = False
        out.append(line)
    path.write_text("".join(out))


EASYVOLCAP_BAD = {
    "intri missing K": (lambda r: _drop_line(r / "intri.yml", "K_01:"), {}, "intri.yml.*K_01"),
    "intri missing names": (lambda r: _drop_line(r / "intri.yml", "names:"), {}, "intri.yml.*names"),
    "extri missing T": (lambda r: _drop_line(r / "extri.yml", "T_02:"), {}, "extri.yml.*T_02"),
    "extri missing R": (lambda r: _drop_line(r / "extri.yml", "R_00:"), {}, "extri.yml.*R_00"),
    "extri not yaml": (lambda r: _corrupt_bytes(r / "extri.yml"), {}, "extri.yml"),
    "intri missing file": (lambda r: (r / "intri.yml").unlink(), dict(format="easyvolcap"), "intri.yml.*not found"),
    "K with NaN": (
        lambda r: (r / "intri.yml").write_text((r / "intri.yml").read_text().replace("data: [ 30", "data: [ .NaN", 1)),
        {},
        "intri.yml.*K_00.*NaN",
    ),
    "missing image": (lambda r: (r / "images" / "01" / "000003.png").unlink(), dict(frame_end=6), "01/000003.png"),
    "missing image folder": (lambda r: os.rename(r / "images" / "02", r / "images" / "x"), {}, "images/02"),
    "range past images": (lambda r: None, dict(frame_end=9), "000006.png.*6 frames.*needs 9"),
    "unknown test camera": (lambda r: None, dict(test_cameras=["cam07"]), "data.test_cameras.*cam07"),
    "bad scene.json": (lambda r: (r / "scene.json").write_text("{fps: "), {}, "scene.json"),
    "unsupported distortion": (lambda r: _replace_entry(r / "intri.yml", "D_01", np.full((1, 6), 0.01)), {},
                               "intri.yml: 'D_01' has 6 values, expected 4 or 5 or 8 or 12 or 14 .*radial-tangential"),
}


def _replace_entry(path: Path, key: str, value: np.ndarray) -> None:
    _drop_line(path, f"{key}:")
    path.write_text(path.read_text() + fx._yml_matrix(key, value))


@pytest.mark.parametrize("case", list(EASYVOLCAP_BAD))
def test_easyvolcap_bad_input_raises_input_error(tmp_path, case):
    mutate, options, pattern = EASYVOLCAP_BAD[case]
    root = fx.write_easyvolcap(tmp_path / "s", n_frames=6)
    mutate(root)
    with pytest.raises(InputError, match=pattern) as err:
        load_scene(DataConfig(**{"path": str(root), **options}))
    assert "\n" not in str(err.value)


LAZY_BAD = {
    "dynerf video removed": ("dynerf", lambda r: (r / "cam01.mp4").unlink(), "cam01.mp4"),
    "dynerf video truncated": (
        "dynerf",
        lambda r: fx.write_video(r / "cam01.mp4", [fx.render_frame(fx.ring_cameras(["x"])[0], 0.0)] * 2, 30.0),
        "cam01.mp4.*decoding stopped",
    ),
    "easyvolcap corrupt image": (
        "easyvolcap",
        lambda r: _corrupt_bytes(r / "images" / "01" / "000002.png"),
        "000002.png",
    ),
    "easyvolcap resized image": (
        "easyvolcap",
        lambda r: cv2.imwrite(str(r / "images" / "01" / "000001.png"), np.zeros((12, 16, 3), np.uint8)),
        "000001.png.*16x12",
    ),
}


@pytest.mark.parametrize("case", list(LAZY_BAD))
def test_decode_failure_after_loading_raises_input_error(tmp_path, case):
    layout, mutate, pattern = LAZY_BAD[case]
    scene = load_scene(DataConfig(path=str(fx.write_scene(layout, tmp_path / "s", n_frames=4))))
    mutate(scene.root)  # the files change between loading and decoding
    with pytest.raises(InputError, match=pattern):
        scene.frames(1)
    assert not list(scene.cache_dir.glob("*.npy"))  # nothing half-written to the cache


# --- Google Immersive: models.json ---------------------------------------------------------------


def _immersive(root: Path) -> Path:
    views = [fx.immersive_view(f"camera_000{i}", (0.3 * i, 0.0, -4.0), (0, 0, 0), scale=1 / 80) for i in (1, 2)]
    frames = {v["name"]: [np.full((24, 32, 3), 40 * k, np.uint8) for k in range(3)] for v in views}
    return fx.write_immersive(root, frames, views)


def _edit_models(root: Path, edit) -> None:
    models = json.loads((root / "models.json").read_text())
    edit(models)
    (root / "models.json").write_text(json.dumps(models))


def _set(index: int, **fields):
    return lambda r: _edit_models(r, lambda m: m[index].update(fields))


def _drop(index: int, field: str):
    return lambda r: _edit_models(r, lambda m: m[index].pop(field))


IMMERSIVE_BAD = {
    "missing field": (_drop(0, "focal_length"), "camera_0001: missing field 'focal_length'"),
    "missing position": (_drop(1, "position"), "camera_0002: missing field 'position'"),
    "NaN principal point": (_set(0, principal_point=[float("nan"), 12.0]), "'principal_point' contains NaN"),
    "Inf orientation": (_set(1, orientation=[0.0, float("inf"), 0.0]), "'orientation' contains NaN or Inf"),
    "principal point of 3": (_set(0, principal_point=[16.0, 12.0, 1.0]), "'principal_point' must be a list of 2"),
    "orientation as a matrix": (_set(0, orientation=np.eye(3).tolist()), "'orientation' must be numbers"),
    "focal length as a list": (_set(0, focal_length=[10.0, 10.0]), "'focal_length' must be one number"),
    "one radial term": (_set(0, radial_distortion=[0.1]), "'radial_distortion' must be a list of 2 or 3 or 4"),
    "third radial term": (_set(0, radial_distortion=[0.1, 0.0, 0.3]), "'radial_distortion' terms after k1, k2"),
    "unknown camera model": (_set(1, projection_type="equirectangular"), "'projection_type' 'equirectangular' is not"),
    "pixel aspect ratio": (_set(0, pixel_aspect_ratio=1.2), "'pixel_aspect_ratio' 1.2 is not supported"),
    "negative focal": (_set(0, focal_length=-3.0), "'focal_length' must be positive"),
    "fractional width": (_set(0, width=31.5), "'width' must be a positive whole number"),
    "boolean height": (_set(0, height=True), "'height' must be a number"),
    "nameless camera": (_drop(0, "name"), "entry 0: 'name'"),
    "camera listed twice": (_set(1, name="camera_0001"), "camera camera_0001 is listed twice"),
    "entry not a dict": (lambda r: _edit_models(r, lambda m: m.append([1, 2])), "entry 2 is not a camera dict"),
    "not a list": (lambda r: (r / "models.json").write_text('{"cameras": []}'), "non-empty JSON list"),
    "not JSON": (lambda r: _corrupt_bytes(r / "models.json"), "models.json: cannot read as JSON"),
    "camera without frames": (lambda r: (r / "camera_0002.mp4").unlink(), "camera_0002.mp4: .* no video"),
    "video of another size": (
        lambda r: fx.write_video(r / "camera_0001.mp4", [np.zeros((24, 40, 3), np.uint8)] * 3, 30.0),
        "camera_0001.mp4: is 40x24 but models.json says 32x24",
    ),
}


@pytest.mark.parametrize("case", list(IMMERSIVE_BAD))
def test_immersive_bad_input_raises_one_line_naming_the_field(tmp_path, case):
    mutate, pattern = IMMERSIVE_BAD[case]
    root = _immersive(tmp_path / "s")
    mutate(root)
    with pytest.raises(InputError, match=pattern) as err:
        load_scene(DataConfig(path=str(root), format="immersive"))
    assert "\n" not in str(err.value)


def test_a_text_file_named_npy_exits_2_with_one_true_line_from_the_cli(tmp_path):
    root = fx.write_dynerf(tmp_path / "s", n_frames=6)
    np.savetxt(root / "poses_bounds.npy", _poses(root))  # numpy.savetxt where numpy.save was meant
    repo = Path(__file__).resolve().parents[2]
    run = subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", "train", f"data.path={root}",
                          "profile=smoke"], cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(repo)},
                         capture_output=True, text=True, timeout=300)
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "poses_bounds.npy: not a NumPy .npy file (it starts with b'" in lines[0]
    assert "pickle" not in lines[0]


def test_malformed_models_json_exits_2_with_one_line_from_the_cli(tmp_path):
    root = _immersive(tmp_path / "s")
    _edit_models(root, lambda m: m[1].update(orientation=[0.1, 0.2]))
    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(repo)}
    run = subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", "train", "data=immersive",
                          f"data.path={root}", "profile=smoke"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert "models.json: camera camera_0002: 'orientation' must be a list of 3 numbers" in lines[0]
