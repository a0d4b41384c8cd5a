"""Check a study scene's synthetic generator arguments without rendering anything."""

from __future__ import annotations

from ftgspp.errors import InputError
from harness.spec.study_schema import StudyScene


def validate_synth(scene: StudyScene) -> None:
    """Check a synthetic scene's generator arguments without rendering (InputError if bad)."""
    if scene.synth is None:
        return
    from ftgspp.data.synthetic.presets import SCENE_LAYOUTS, resolve_config

    args = dict(scene.synth)
    where = f"scene '{scene.name}' synth"
    from harness.spec import known_scene, sphere_scene

    own = {known_scene.PRESET: known_scene.resolve, sphere_scene.PRESET: sphere_scene.resolve}  # the harness's scenes
    if args.get("preset") in own:
        try:
            own[args["preset"]]({k: v for k, v in args.items() if k != "preset"})
        except (InputError, TypeError) as err:
            raise InputError(where, str(err)) from None
        return
    if args.get("layout") not in SCENE_LAYOUTS:
        raise InputError(where, f"unknown layout '{args.get('layout')}' (choose from {', '.join(SCENE_LAYOUTS)})")
    extra = {k: v for k, v in args.items() if k not in {"preset", "seed", "layout"}}
    try:
        resolve_config(args["preset"], args["seed"], **extra)
    except InputError as err:
        raise InputError(where, str(err)) from None
    except TypeError as err:
        raise InputError(where, str(err)) from None
