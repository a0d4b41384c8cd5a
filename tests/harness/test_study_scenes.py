"""Synthetic study scenes: generated once, reused, regenerated when their arguments change."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from ftgspp.data.synthetic.presets import resolve_config
from ftgspp.errors import InputError
from harness.run.scenes import MARKER, WRITER_VERSION, ensure_scene
from harness.spec.study_schema import StudyScene
from harness.spec.synth import validate_synth


def _scene(tmp_path: Path, **synth) -> StudyScene:
    args = {"preset": "studio", "seed": 0, "layout": "dynerf", **synth}
    return StudyScene("s", args, (), "", str(tmp_path / "s"))


def test_generate_once_then_reuse_then_regenerate_on_change(tmp_path: Path) -> None:
    calls = []

    def gen(out, layout, preset, seed, **extra):
        calls.append((layout, preset, seed, extra))
        Path(out).mkdir(parents=True)
        (Path(out) / "scene.txt").write_text(str(extra))

    assert ensure_scene(_scene(tmp_path, n_cameras=6), gen, echo=lambda s: None)
    assert not ensure_scene(_scene(tmp_path, n_cameras=6), gen, echo=lambda s: None)
    assert ensure_scene(_scene(tmp_path, n_cameras=5), gen, echo=lambda s: None)
    assert calls == [("dynerf", "studio", 0, {"n_cameras": 6}), ("dynerf", "studio", 0, {"n_cameras": 5})]
    assert (tmp_path / "s" / "scene.txt").read_text() == "{'n_cameras': 5}"
    assert not (tmp_path / "s.partial").exists()


def test_a_scene_written_by_ftgspp_synth_with_the_same_args_is_adopted(tmp_path: Path) -> None:
    scene = _scene(tmp_path, color_shift=2.0)
    params = dataclasses.asdict(resolve_config("studio", 0, color_shift=2.0))
    params = {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}
    (tmp_path / "s" / "gt").mkdir(parents=True)
    meta = {"layout": "dynerf", "params": params, "files": {"clean": "clean/{camera}.npy"}}
    (tmp_path / "s" / "gt" / "scene.json").write_text(json.dumps(meta))
    assert not ensure_scene(scene, lambda *a, **k: pytest.fail("must not regenerate"), echo=lambda s: None)
    assert (tmp_path / "s" / MARKER).is_file()


def test_a_scene_of_an_older_writer_is_regenerated(tmp_path: Path) -> None:
    # without the held-out camera's noise-free frames (written since issue 54), or with a marker of
    # the writer before, a folder is written again; the arguments alone would not tell
    scene = _scene(tmp_path)
    params = dataclasses.asdict(resolve_config("studio", 0))
    params = {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}
    (tmp_path / "s" / "gt").mkdir(parents=True)
    (tmp_path / "s" / "gt" / "scene.json").write_text(json.dumps({"layout": "dynerf", "params": params}))
    made = []
    assert ensure_scene(scene, lambda out, *a, **k: made.append(Path(out).mkdir(parents=True)), echo=lambda s: None)
    assert made and json.loads((tmp_path / "s" / MARKER).read_text())["_writer"] == WRITER_VERSION
    (tmp_path / "s" / MARKER).write_text(json.dumps(dict(scene.synth), sort_keys=True))  # an old marker
    assert ensure_scene(scene, lambda out, *a, **k: Path(out).mkdir(parents=True), echo=lambda s: None)


def test_bad_generator_arguments_are_input_errors(tmp_path: Path) -> None:
    for bad in ({"preset": "nope"}, {"n_cameras": 1}, {"wobble": 3}, {"layout": "colmap"}):
        with pytest.raises(InputError, match="scene 's' synth"):
            validate_synth(_scene(tmp_path, **bad))
