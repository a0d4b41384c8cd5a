"""Synthetic study scenes, generated on demand into ``data/synth/<name>``.

A scene with ``synth: {preset, seed, layout, ...}`` is written by
``ftgspp.data.synthetic.generate(out, layout, preset, seed, **extra)`` the first time a
study needs it. A marker file records the arguments; a folder whose marker differs (the
study file changed) is regenerated, one with the same marker is reused, and so is a folder
without a marker that ``ftgspp synth`` wrote with the same arguments. Generation
writes into a temporary sibling folder and renames it, so a killed run never leaves a
half-written scene behind.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any, Callable

from ftgspp.errors import InputError
from harness.studies import SceneSpec

MARKER = ".study_synth.json"
# generate(out, layout, preset, seed, **extra)
Generator = Callable[..., Any]


def validate_synth(scene: SceneSpec) -> None:
    """Check a synthetic scene's generator arguments without rendering (InputError if bad)."""
    if scene.synth is None:
        return
    from ftgspp.data.synthetic import LAYOUTS, resolve_config

    args = dict(scene.synth)
    where = f"scene '{scene.name}' synth"
    if args.get("layout") not in LAYOUTS:
        raise InputError(where, f"unknown layout '{args.get('layout')}' (choose from {', '.join(LAYOUTS)})")
    extra = {k: v for k, v in args.items() if k not in {"preset", "seed", "layout"}}
    try:
        resolve_config(args["preset"], args["seed"], **extra)
    except InputError as err:
        raise InputError(where, str(err)) from None
    except TypeError as err:
        raise InputError(where, str(err)) from None


def _generated_with(out: Path, args: dict[str, Any]) -> bool:
    """Whether ``out`` holds a scene ``ftgspp synth`` wrote with exactly these arguments."""
    meta_file = out / "gt" / "scene.json"
    if not meta_file.is_file():
        return False
    try:
        from ftgspp.data.synthetic import resolve_config

        meta = json.loads(meta_file.read_text())
        extra = {k: v for k, v in args.items() if k not in {"preset", "seed", "layout"}}
        want = dataclasses.asdict(resolve_config(args["preset"], args["seed"], **extra))
    except Exception:  # unreadable metadata or arguments: regenerate
        return False
    want = {k: list(v) if isinstance(v, tuple) else v for k, v in want.items()}
    return meta.get("layout") == args["layout"] and meta.get("params") == want


def _default_generator() -> Generator:
    from ftgspp.data.synthetic import generate

    return generate


def ensure_scene(scene: SceneSpec, generate: Generator | None = None, echo: Callable[[str], None] = print) -> bool:
    """Make sure a synthetic scene exists; returns True if it was (re)generated."""
    if scene.synth is None:
        return False
    out = Path(scene.synth_dir)
    marker = out / MARKER
    args = dict(scene.synth)
    if marker.is_file() and json.loads(marker.read_text()) == args:
        return False
    if not marker.exists() and _generated_with(out, args):  # e.g. by `ftgspp synth` (make demo)
        marker.write_text(json.dumps(args, sort_keys=True))
        return False
    echo(f"generating synthetic scene '{scene.name}' into {out} ({json.dumps(args, sort_keys=True)})")
    tmp = out.with_name(out.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.parent.mkdir(parents=True, exist_ok=True)
    extra = {k: v for k, v in args.items() if k not in {"preset", "seed", "layout"}}
    (generate or _default_generator())(tmp, args["layout"], args["preset"], args["seed"], **extra)
    (tmp / MARKER).write_text(json.dumps(args, sort_keys=True))
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return True
