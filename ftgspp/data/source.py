"""What a scene-format reader hands to the loader, and how cameras are named.

``SceneSource`` is the metadata a format module (``dynerf.py``, ``easyvolcap.py``) reads
from a scene folder; ``kept_cameras`` / ``match_camera`` resolve user-given camera names.
They live here, below both the loader and the format modules, so neither imports the other
in a loop.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.errors import InputError

# read_frames(camera_index, frame_ids [F]) -> one uint8 [H, W, 3] RGB frame per id, at the
# camera's full (file) resolution, already undistorted.
FrameReader = Callable[[int, Sequence[int]], Iterator[np.ndarray]]


@dataclass
class SceneSource:
    """What a format module reads from a scene folder (metadata only, no frames)."""

    cameras: list[Camera]  # full resolution, in the layout's camera order
    frame_counts: list[int]  # per camera: frames [0, count) are available
    limit_files: list[Path]  # per camera: the file that bounds its frame count (for messages)
    fps: float
    read_frames: FrameReader
    fingerprint_files: list[Path] = field(default_factory=list)  # their size + mtime key the cache
    near: float | None = None
    far: float | None = None


def camera_number(name: str) -> int | None:
    """The camera number in ``"cam07"``, ``"07"`` or ``"7"`` (``7``); None for other names."""
    m = re.fullmatch(r"(?:cam)?(\d+)", name.strip(), flags=re.IGNORECASE)
    return int(m.group(1)) if m else None


def match_camera(wanted: str, names: Sequence[str]) -> int | None:
    """Index of camera ``wanted`` in ``names``: exact name first, then the same camera number."""
    if wanted in names:
        return list(names).index(wanted)
    number = camera_number(wanted)
    if number is not None:
        for i, name in enumerate(names):
            if camera_number(name) == number:
                return i
    return None


def kept_cameras(names: Sequence[str], drop_cameras: Sequence[str], root: Path) -> list[int]:
    """Indices of ``names`` left after removing ``drop_cameras`` (matched like test cameras)."""
    dropped = set()
    for wanted in drop_cameras:
        i = match_camera(wanted, names)
        if i is None:
            raise InputError(
                "data.drop_cameras", f"camera {wanted!r} not found in {root} (cameras: {', '.join(names)})"
            )
        dropped.add(i)
    if len(dropped) == len(names):
        raise InputError("data.drop_cameras", f"drops every camera of {root}")
    return [i for i in range(len(names)) if i not in dropped]
