"""Procedural textures and shading of the synthetic scenes (``ftgspp synth``).

Every surface carries a procedural texture in surface coordinates (u, v) in world units:
a smooth colour gradient, a large soft checker, a few low-frequency waves, mid-frequency
value-noise blotches and jittered marks (discs, squares, rings, ellipses that vary only in
brightness: features for SIFT that survive chroma subsampling). Shading is Lambertian with
one directional light plus ambient.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

LIGHT_DIR = np.array([0.35, -0.8, -0.5]) / np.linalg.norm([0.35, -0.8, -0.5])  # towards the light
AMBIENT = 0.45
DIFFUSE = 0.55


def _hash01(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Deterministic per-cell pseudo-random numbers in [0, 1) from integer cell ids."""
    h = ix.astype(np.int64).astype(np.uint32) * np.uint32(0x8DA6B343)
    h ^= iy.astype(np.int64).astype(np.uint32) * np.uint32(0xD8163841)
    h ^= np.uint32((salt * 0x9E3779B1) & 0xFFFFFFFF)
    h ^= h >> np.uint32(13)
    h *= np.uint32(0x5BD1E995)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x27D4EB2F)
    h ^= h >> np.uint32(16)
    return h.astype(np.float64) / 2.0**32


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """HSV (hue in degrees, s and v in [0, 1]) to RGB in [0, 1]; ``[..., 3] -> [..., 3]``."""
    hsv = np.asarray(hsv, dtype=np.float32)
    rgb = cv2.cvtColor(hsv.reshape(1, -1, 3), cv2.COLOR_HSV2RGB)
    return rgb.reshape(hsv.shape).astype(np.float64)


@dataclass(frozen=True)
class Texture:
    """Procedural albedo in surface coordinates (u, v), both in world units."""

    color_a: np.ndarray  # [3] gradient start
    color_b: np.ndarray  # [3] gradient end
    accent: np.ndarray  # [3] checker colour
    gradient_dir: np.ndarray  # [2] unit direction of the gradient in (u, v)
    gradient_period: float  # world units
    gradient_phase: float
    checker_period: float  # size of one checker square
    checker_strength: float  # 0 = no checker, 1 = full accent colour
    waves: np.ndarray  # [K, 4] rows (fu, fv, phase, amplitude): luminance ripples
    mark_cell: float  # jittered-grid cell size of the marks
    mark_gains: np.ndarray  # [M] brightness factors of the marks (luminance detail, same hue)
    salt: int
    period_u: float | None = None  # u wraps with this period (sphere longitude)
    mark_fraction: float = 0.7  # share of grid cells holding a mark
    detail: float = 1.0  # scales the checker, noise, waves and marks; 0 leaves the smooth gradient only

    def albedo(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Albedo for surface points ``u, v [N]`` -> ``[N, 3]`` in (0, 1)."""
        g = 0.5 + 0.5 * np.sin(2 * np.pi * (self.gradient_dir[0] * u + self.gradient_dir[1] * v)
                               / self.gradient_period + self.gradient_phase)
        col = self.color_a + (self.color_b - self.color_a) * g[:, None]
        s = np.sin(np.pi * u / self.checker_period) * np.sin(np.pi * v / self.checker_period)
        chk = self.checker_strength * self.detail * (0.5 + 0.5 * np.tanh(6.0 * s))
        col = col * (1 - chk[:, None]) + self.accent * chk[:, None]
        lum = 1.0 + 0.4 * self.detail * self._value_noise(u, v, 0.4 * self.mark_cell)
        for fu, fv, ph, amp in self.waves:
            lum += amp * self.detail * np.cos(2 * np.pi * (fu * u + fv * v) + ph)
        w, gain = self._marks(u, v)
        col = col * (lum * (1 + (gain - 1) * w * self.detail))[:, None]
        return np.clip(col, 0.03, 0.95)

    def _cells(self, u: np.ndarray, v: np.ndarray, cell: float):
        """Integer cell ids (wrapped in u when periodic) and in-cell coordinates in [0, 1)."""
        cu, cv = u / cell, v / cell
        iu, iv = np.floor(cu), np.floor(cv)
        fu, fv = cu - iu, cv - iv
        if self.period_u is not None:
            iu = np.mod(iu, round(self.period_u / cell))
        return iu, iv, fu, fv

    def _value_noise(self, u: np.ndarray, v: np.ndarray, cell: float) -> np.ndarray:
        """Smooth value noise in [-1, 1] with feature size ``cell`` (mid-frequency blotches)."""
        iu, iv, fu, fv = self._cells(u, v, cell)
        n_u = round(self.period_u / cell) if self.period_u is not None else None
        su, sv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)

        def corner(du: int, dv: int) -> np.ndarray:
            cu = iu + du if n_u is None else np.mod(iu + du, n_u)
            return _hash01(cu, iv + dv, self.salt * 8 + 7)

        top = corner(0, 0) * (1 - su) + corner(1, 0) * su
        bottom = corner(0, 1) * (1 - su) + corner(1, 1) * su
        return 2 * (top * (1 - sv) + bottom * sv) - 1

    def _marks(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Jittered-grid marks (discs, rotated squares, rings, ellipses), at most one per cell.

        Returns the coverage ``w [N]`` in [0, 1] and the brightness gain ``[N]`` of the mark.
        """
        iu, iv, fu, fv = self._cells(u, v, self.mark_cell)
        h = [_hash01(iu, iv, self.salt * 8 + k) for k in range(7)]
        r = 0.12 + 0.16 * h[2]
        margin = 1.15 * r  # rotated squares reach sqrt(2) * 0.8 r
        dx = fu - (margin + (1 - 2 * margin) * h[0])
        dy = fv - (margin + (1 - 2 * margin) * h[1])
        ang = 2 * np.pi * h[5]
        rx, ry = dx * np.cos(ang) + dy * np.sin(ang), -dx * np.sin(ang) + dy * np.cos(ang)
        shape = np.minimum((h[6] * 4).astype(int), 3)
        disc = r - np.hypot(rx, ry)
        square = 0.8 * r - np.maximum(np.abs(rx), np.abs(ry))
        ring = 0.3 * r - np.abs(np.hypot(rx, ry) - 0.7 * r)
        ellipse = r - np.hypot(rx, 1.8 * ry)
        edge = np.select([shape == 0, shape == 1, shape == 2], [disc, square, ring], ellipse)  # > 0 inside
        w = np.clip(edge / 0.06 + 0.5, 0.0, 1.0) * (h[3] < self.mark_fraction)
        gain = self.mark_gains[np.minimum((h[4] * len(self.mark_gains)).astype(int), len(self.mark_gains) - 1)]
        return w, gain


def make_texture(rng: np.random.Generator, hue: float, scale: float, salt: int,
                 period_u: float | None = None, vivid: bool = False) -> Texture:
    """A random texture around ``hue`` (degrees) with feature size proportional to ``scale``.

    With ``period_u`` every component is made periodic in u (for wrapping onto a sphere);
    ``vivid`` gives saturated colours and a strong checker (for the moving objects).
    """
    def col(h: float, s: float, v: float) -> np.ndarray:
        return hsv_to_rgb(np.array([h % 360, min(s, 1.0), v]))

    sat = 1.6 if vivid else 1.0
    color_a = col(hue + rng.uniform(-15, 15), sat * rng.uniform(0.35, 0.6), rng.uniform(0.6, 0.75))
    color_b = col(hue + rng.uniform(30, 70), sat * rng.uniform(0.3, 0.6), rng.uniform(0.7, 0.85))
    accent = col(hue + rng.uniform(-40, 40), sat * rng.uniform(0.3, 0.6), rng.uniform(0.25, 0.4))
    angle = rng.uniform(0, np.pi)
    gradient_dir = np.array([np.cos(angle), np.sin(angle)])
    checker = 1.1 * scale
    waves = []
    for _ in range(3):
        f = rng.uniform(1.0, 2.2) / scale  # cycles per world unit
        a = rng.uniform(0, np.pi)
        waves.append([f * np.cos(a), f * np.sin(a), rng.uniform(0, 2 * np.pi), rng.uniform(0.04, 0.08)])
    waves = np.array(waves)
    mark_cell = 0.5 * scale
    if period_u is not None:  # make u-periodic: integer number of periods around
        checker = period_u / (2 * max(1, round(period_u / (2 * checker))))
        waves[:, 0] = np.round(waves[:, 0] * period_u) / period_u
        mark_cell = period_u / max(1, round(period_u / mark_cell))
        gradient_dir = np.array([0.0, 1.0])
    mark_gains = np.array([0.3, 0.5, 1.45, 1.7])
    strength = rng.uniform(0.65, 0.8) if vivid else rng.uniform(0.35, 0.55)
    return Texture(color_a, color_b, accent, gradient_dir, 8.0 * scale, rng.uniform(0, 2 * np.pi),
                   checker, strength, waves, mark_cell, mark_gains, salt, period_u)


def shade(albedo: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Lambertian shading with ambient; ``[N, 3], [N, 3] -> [N, 3]``."""
    lam = np.clip(normal @ LIGHT_DIR, 0.0, None)
    return albedo * (AMBIENT + DIFFUSE * lam)[:, None]
