"""Procedural multi-view dynamic scenes with ground truth (``ftgspp synth``).

- ``presets``: ``SynthConfig``, the presets and their validation;
- ``content``: the room, props, moving balls and rig, and one camera's frames;
- ``geometry``, ``textures``, ``raycast``, ``rig``: surfaces, their shading, the ray caster and the camera rig;
- ``layouts``: the lens layouts (Immersive fisheye, ENeRF-Outdoor distortion);
- ``formats``: the on-disk files (videos, camera files, ground-truth JSON);
- ``build``: ``generate(out, ...)`` and the command line; ``pool``: cameras rendered in worker processes.

The package imports nothing itself, so a worker process (``python -m ftgspp.data.synthetic.pool``)
loads only the modules its task needs.
"""
