"""Surfaces and moving objects of the synthetic scenes (``ftgspp synth``).

The world frame is OpenCV-like: x right, y down, z forward (from the camera rig into the
room). Units are arbitrary "metres"; time is in seconds.

A scene (``SceneContent``) is a closed room of textured planes (``Quad``) and boxes
(``Box``) that looks out onto a far textured backdrop, and moving textured spheres
(``MovingSphere``) on a straight (``LinearPath``) or circular (``ArcPath``) path. Each
surface intersects rays and shades its own points; ``raycast`` composes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ftgspp.data.synthetic.textures import Texture, shade


@dataclass(frozen=True)
class Quad:
    """A plane patch ``origin + u * u_axis + v * v_axis``; unbounded when ``extent`` is None."""

    name: str
    origin: np.ndarray  # [3]
    u_axis: np.ndarray  # [3] unit
    v_axis: np.ndarray  # [3] unit, orthogonal to u_axis
    normal: np.ndarray  # [3] unit, towards the visible side
    texture: Texture
    extent: tuple[float, float, float, float] | None = None  # (u0, u1, v0, v1)
    holes: tuple[tuple[float, float, float, float], ...] = ()  # rectangles cut out

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Ray parameter of the hit for rays ``origin [3] + t dirs [N, 3]`` -> ``[N]`` (inf = miss)."""
        denom = dirs @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.origin - origin) @ self.normal) / denom
        t = np.where(np.isfinite(t) & (t > 1e-6), t, np.inf)
        if self.extent is None and not self.holes:
            return t
        hit = np.isfinite(t)
        u, v = self.uv(origin + np.where(hit, t, 0.0)[:, None] * dirs)
        if self.extent is not None:
            u0, u1, v0, v1 = self.extent
            hit &= (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)
        for u0, u1, v0, v1 in self.holes:
            hit &= ~((u > u0) & (u < u1) & (v > v0) & (v < v1))
        return np.where(hit, t, np.inf)

    def uv(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Surface coordinates of points on the plane, ``[N, 3] -> ([N], [N])``."""
        d = points - self.origin
        return d @ self.u_axis, d @ self.v_axis

    def shade_points(self, points: np.ndarray) -> np.ndarray:
        """Shaded colour of points on the plane, ``[N, 3] -> [N, 3]``."""
        albedo = self.texture.albedo(*self.uv(points))
        return shade(albedo, np.broadcast_to(self.normal, albedo.shape))


@dataclass(frozen=True)
class Box:
    """A textured axis-aligned box ``[lo, hi]`` (slab intersection)."""

    name: str
    lo: np.ndarray  # [3]
    hi: np.ndarray  # [3]
    texture: Texture

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Ray parameter of the first hit, ``[N, 3] -> [N]`` (inf = miss); the camera is outside."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (self.lo - origin) / dirs
            t2 = (self.hi - origin) / dirs
        t_in = np.nanmax(np.minimum(t1, t2), axis=1)
        t_out = np.nanmin(np.maximum(t1, t2), axis=1)
        return np.where((t_in <= t_out) & (t_in > 1e-6), t_in, np.inf)

    def shade_points(self, points: np.ndarray) -> np.ndarray:
        """Shaded colour of points on the box surface, ``[N, 3] -> [N, 3]``."""
        gaps = np.concatenate([np.abs(points - self.lo), np.abs(points - self.hi)], axis=1)  # [N, 6]
        face = np.argmin(gaps, axis=1)
        axis = face % 3
        normal = np.zeros_like(points)
        normal[np.arange(len(points)), axis] = np.where(face < 3, -1.0, 1.0)
        rel = points - self.lo
        # face coordinates: the two coordinates other than the face axis (+ an offset per face)
        u = np.where(axis == 0, rel[:, 2], rel[:, 0]) + 7.0 * face
        v = np.where(axis == 1, rel[:, 2], rel[:, 1])
        return shade(self.texture.albedo(u, v), normal)


# ----------------------------------------------------------------------------- moving objects


@dataclass(frozen=True)
class LinearPath:
    """Constant-velocity motion through ``mid`` at ``t_mid``, reflected at ``half_range``.

    ``p(t) = mid + fold(velocity (t - t_mid))``: the ball goes back and forth along one line,
    turning around ``half_range`` units from ``mid``, so long clips stay inside the room.
    The default clips never reach a turning point.
    """

    mid: np.ndarray  # [3] position at t_mid
    velocity_ws: np.ndarray  # [3] world units per second (before any reflection)
    t_mid: float
    half_range: float = 1.0
    kind: str = "linear"

    def _fold(self, t: float) -> tuple[float, float]:
        """Signed distance from ``mid`` along the line and the direction sign at ``t``."""
        L = self.half_range
        w = np.mod(np.linalg.norm(self.velocity_ws) * (t - self.t_mid) + L, 4 * L)
        return L - abs(w - 2 * L), (1.0 if w < 2 * L else -1.0)

    def position(self, t: float) -> np.ndarray:
        """World position ``[3]`` at time ``t`` (seconds)."""
        speed = np.linalg.norm(self.velocity_ws)
        if speed == 0:
            return self.mid.copy()
        return self.mid + self._fold(t)[0] * self.velocity_ws / speed

    def velocity(self, t: float) -> np.ndarray:
        """World velocity ``[3]`` (units/s) at time ``t``."""
        return self.velocity_ws * self._fold(t)[1]


@dataclass(frozen=True)
class ArcPath:
    """Uniform circular motion ``c + r (cos a e1 + sin a e2)``, ``a = phase + omega t``."""

    centre: np.ndarray  # [3]
    radius: float
    omega: float  # rad/s
    phase: float  # rad at t = 0
    e1: np.ndarray  # [3] unit
    e2: np.ndarray  # [3] unit, orthogonal to e1
    kind: str = "curved"

    def position(self, t: float) -> np.ndarray:
        """World position ``[3]`` at time ``t`` (seconds)."""
        a = self.phase + self.omega * t
        return self.centre + self.radius * (np.cos(a) * self.e1 + np.sin(a) * self.e2)

    def velocity(self, t: float) -> np.ndarray:
        """World velocity ``[3]`` (units/s) at time ``t``."""
        a = self.phase + self.omega * t
        return self.radius * self.omega * (-np.sin(a) * self.e1 + np.cos(a) * self.e2)


@dataclass(frozen=True)
class MovingSphere:
    """A textured sphere following ``path`` and spinning at ``spin`` rad/s about ``spin_axis``."""

    name: str
    label: int  # value in the object masks (1, 2, ...)
    radius: float
    path: LinearPath | ArcPath
    texture: Texture  # in (longitude * radius, latitude * radius) coordinates
    spin: float = 0.0
    spin_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, -1.0, 0.0]))
    visible: tuple[float, float] = (-np.inf, np.inf)  # [appears, disappears) in seconds
    flicker: float = 0.0  # strength of a stochastic per-frame change of its colours (a flame)
    role: str = "moving"  # moving | transient | flame: what the object stands for (objects.json)

    def present(self, t: float) -> bool:
        """Whether the object exists at time ``t`` (seconds)."""
        return bool(self.visible[0] <= t < self.visible[1])

    def transient(self) -> bool:
        """Whether the object exists for only part of the clip."""
        return bool(np.isfinite(self.visible).any())

    def appearance(self, t: float, points: np.ndarray) -> np.ndarray:
        """Multiplicative colour change ``[N, 3]`` at time ``t`` of object-frame ``points [N, 3]``:
        ones, or for a flame a smooth random field redrawn every frame (geometry unchanged)."""
        if self.flicker == 0:
            return np.ones_like(points)
        rng = np.random.default_rng([self.label, int(round(t * 1000))])  # a new draw per time
        waves = rng.normal(0.0, 3.0, (4, 3))  # 4 plane waves (wave vectors) over the unit sphere
        phases = rng.uniform(0, 2 * np.pi, 4)
        field_ = np.sin(points @ waves.T + phases).mean(axis=1)  # [N] in [-1, 1]
        tint = np.array([1.0, 0.55, 0.2]) * rng.uniform(0.6, 1.0)  # hot colours change the most in red
        return np.clip(1.0 + self.flicker * field_[:, None] * tint, 0.2, 2.0)

    def angular_velocity(self) -> np.ndarray:
        """World-space angular velocity, rad/s, ``[3]``."""
        return self.spin * self.spin_axis + 0.0  # + 0.0: no negative zeros

    def rotation(self, t: float) -> np.ndarray:
        """Object-to-world rotation at time ``t`` (``[3, 3]``)."""
        rot, _ = cv2.Rodrigues((self.angular_velocity() * t).reshape(3, 1))
        return rot


@dataclass
class SceneContent:
    """Everything the ray caster needs: static surfaces and moving objects."""

    static: list[Quad | Box]
    objects: list[MovingSphere]
