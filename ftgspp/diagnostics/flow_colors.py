"""Colour coding of flow fields for the diagnostics (no plotting, no model code).

Used by ``ftgspp.diagnostics.figures`` (and the tests); it imports no other diagnostics
module.
"""

from __future__ import annotations

import numpy as np


def flow_to_rgb(flow: np.ndarray, max_magnitude: float | None = None, mask: np.ndarray | None = None,
                masked_color: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> tuple[np.ndarray, float]:
    """Optical-flow colour coding of ``flow [H, W, 2]`` (x right, y down): ``(rgb [H, W, 3], max)``.

    Hue = direction: +x red (0°), +y/down chartreuse (90°), −x cyan (180°), −y/up violet
    (270°); saturation 1; value = |flow| / max_magnitude (clipped to 1; default: the 99th
    percentile of |flow| over ``mask``). Pixels outside ``mask`` get ``masked_color``.
    """
    from matplotlib.colors import hsv_to_rgb

    mag = np.linalg.norm(flow, axis=-1)
    sel = mag[mask] if mask is not None else mag.reshape(-1)
    if max_magnitude is None:
        max_magnitude = float(np.percentile(sel, 99)) if sel.size else 0.0
    max_magnitude = max(float(max_magnitude), 1e-9)
    hue = (np.arctan2(flow[..., 1], flow[..., 0]) / (2 * np.pi)) % 1.0
    hsv = np.stack([hue, np.ones_like(hue), np.clip(mag / max_magnitude, 0.0, 1.0)], axis=-1)
    rgb = hsv_to_rgb(hsv)
    if mask is not None:
        rgb[~mask] = masked_color
    return rgb, max_magnitude


def color_wheel(size: int = 101) -> np.ndarray:
    """Legend for ``flow_to_rgb``: ``[size, size, 3]``, image coordinates (x right, y down),
    full speed at the rim, white outside the disc."""
    r = (size - 1) / 2.0
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    flow = np.stack([(xx - r) / r, (yy - r) / r], axis=-1)
    inside = np.linalg.norm(flow, axis=-1) <= 1.0
    return flow_to_rgb(flow, 1.0, mask=inside)[0]
