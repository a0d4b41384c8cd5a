"""Synthetic study scenes, generated on demand into ``data/synth/<name>``.

A scene with ``synth: {preset, seed, layout, ...}`` is written by
``ftgspp.data.synthetic.build.generate(out, layout, preset, seed, **extra)`` (for the preset
``known_size``: ``run.known_size.generate``, a scene drawn from a known number of Gaussians; for
``spheres``: ``run.spheres.generate``, ray-cast spheres from a writer independent of ftgspp's) the
first time a study needs it. A marker file records the arguments; a folder whose marker differs (the
study file changed) is regenerated, one with the same marker is reused, and so is a folder
without a marker that ``ftgspp synth`` wrote with the same arguments. Generation
writes into a temporary sibling folder and renames it, so a killed run never leaves a
half-written scene behind.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import json
import shutil
from pathlib import Path
from typing import Any, Callable, Iterator

from harness.run import known_size, spheres
from harness.spec.study_schema import StudyScene

MARKER = ".study_synth.json"
# The scene writers' output version, kept in the marker beside the arguments: a folder written by an
# older writer is regenerated. 2 (issue 54): the held-out camera's noise-free frames (gt/clean/),
# the known-size scene's ground truth. Not part of the arguments, so no run's config hash changes.
WRITER_VERSION = 2
# generate(out, layout, preset, seed, **extra)
Generator = Callable[..., Any]
# the harness's own scenes: preset -> its writer
HARNESS_PRESETS: dict[str, Generator] = {known_size.PRESET: known_size.generate, spheres.PRESET: spheres.generate}


def _generated_with(out: Path, args: dict[str, Any]) -> bool:
    """Whether ``out`` holds a scene ``ftgspp synth`` wrote with exactly these arguments."""
    meta_file = out / "gt" / "scene.json"
    if not meta_file.is_file():
        return False
    try:
        from ftgspp.data.synthetic.presets import resolve_config

        meta = json.loads(meta_file.read_text())
        extra = {k: v for k, v in args.items() if k not in {"preset", "seed", "layout"}}
        want = dataclasses.asdict(resolve_config(args["preset"], args["seed"], **extra))
    except Exception:  # unreadable metadata or arguments: regenerate
        return False
    want = {k: list(v) if isinstance(v, tuple) else v for k, v in want.items()}
    current = "clean" in (meta.get("files") or {})  # written since WRITER_VERSION 2
    return current and meta.get("layout") == args["layout"] and meta.get("params") == want


def _default_generator() -> Generator:
    from ftgspp.data.synthetic.build import generate

    return generate


def ensure_scene(scene: StudyScene, generate: Generator | None = None, echo: Callable[[str], None] = print) -> bool:
    """Make sure a synthetic scene exists; returns True if it was (re)generated."""
    if scene.synth is None:
        return False
    out = Path(scene.synth_dir)
    marker = out / MARKER
    args = dict(scene.synth)
    stamp = json.dumps({**args, "_writer": WRITER_VERSION}, sort_keys=True)
    if marker.is_file() and json.loads(marker.read_text()) == json.loads(stamp):
        return False
    if not marker.exists() and _generated_with(out, args):  # e.g. by `ftgspp synth` (make demo)
        marker.write_text(stamp)
        return False
    echo(f"generating synthetic scene '{scene.name}' into {out} ({json.dumps(args, sort_keys=True)})")
    tmp = out.with_name(out.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    extra = {k: v for k, v in args.items() if k not in {"preset", "seed", "layout"}}
    if generate is None:  # the harness's own scenes have their own writers
        generate = HARNESS_PRESETS.get(args["preset"])
    (generate or _default_generator())(tmp, args["layout"], args["preset"], args["seed"], **extra)
    (tmp / MARKER).write_text(stamp)
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return True


@contextlib.contextmanager
def scene_lock(scene: StudyScene) -> Iterator[None]:
    """An exclusive ``fcntl`` lock on ``<scene folder>.lock`` (synthetic scenes only)."""
    if scene.synth is None:
        yield
        return
    lock = Path(scene.synth_dir).with_name(Path(scene.synth_dir).name + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
