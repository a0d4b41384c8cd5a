"""Geometry, textures and a vectorised numpy ray caster for the synthetic scenes.

The world frame is OpenCV-like: x right, y down, z forward (from the camera rig into the
room). Units are arbitrary "metres"; time is in seconds.

A scene is a closed room (floor, ceiling, side walls, a back wall with a window) that
looks out onto a far textured backdrop, a few static props, and moving textured
spheres. Every surface carries a procedural texture in surface coordinates (u, v) in
world units: a smooth colour gradient, a large soft checker, a few low-frequency waves,
mid-frequency value-noise blotches and jittered marks (discs, squares, rings, ellipses
that vary only in brightness: features for SIFT that survive chroma subsampling).
Shading is Lambertian with one directional light plus ambient.

Rays are generated with the camera model of ``ftgspp.data.scene.Camera``: pixel
(row i, col j) is centred at (x=j, y=i); ray directions are scaled so that their
camera-z component is 1, so the hit parameter ``t`` *is* the camera z-depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ftgspp.data.scene import Camera

LIGHT_DIR = np.array([0.35, -0.8, -0.5]) / np.linalg.norm([0.35, -0.8, -0.5])  # towards the light
AMBIENT = 0.45
DIFFUSE = 0.55


# ----------------------------------------------------------------------------- textures


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

    def albedo(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Albedo for surface points ``u, v [N]`` -> ``[N, 3]`` in (0, 1)."""
        g = 0.5 + 0.5 * np.sin(2 * np.pi * (self.gradient_dir[0] * u + self.gradient_dir[1] * v)
                               / self.gradient_period + self.gradient_phase)
        col = self.color_a + (self.color_b - self.color_a) * g[:, None]
        s = np.sin(np.pi * u / self.checker_period) * np.sin(np.pi * v / self.checker_period)
        chk = self.checker_strength * (0.5 + 0.5 * np.tanh(6.0 * s))
        col = col * (1 - chk[:, None]) + self.accent * chk[:, None]
        lum = 1.0 + 0.4 * self._value_noise(u, v, 0.4 * self.mark_cell)
        for fu, fv, ph, amp in self.waves:
            lum += amp * np.cos(2 * np.pi * (fu * u + fv * v) + ph)
        w, gain = self._marks(u, v)
        col = col * (lum * (1 + (gain - 1) * w))[:, None]
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


# ----------------------------------------------------------------------------- surfaces


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
        speed = np.linalg.norm(self.velocity_ws)
        if speed == 0:
            return self.mid.copy()
        return self.mid + self._fold(t)[0] * self.velocity_ws / speed

    def velocity(self, t: float) -> np.ndarray:
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
        a = self.phase + self.omega * t
        return self.centre + self.radius * (np.cos(a) * self.e1 + np.sin(a) * self.e2)

    def velocity(self, t: float) -> np.ndarray:
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


# ----------------------------------------------------------------------------- cameras and rays


def look_at(center: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, -1.0, 0.0])) -> np.ndarray:
    """World-to-camera rotation (OpenCV axes) of a camera at ``center`` looking at ``target``."""
    z = target - center
    z = z / np.linalg.norm(z)
    y = -up - (-up @ z) * z  # image down = world down projected off the viewing axis
    y = y / np.linalg.norm(y)
    x = np.cross(y, z)
    return np.stack([x, y, z])  # rows are the camera axes in world coordinates


def make_rig(n_cameras: int, width: int, height: int, hfov_deg: float, arc_deg: float,
             radius: float, target: np.ndarray, eye_height: float) -> list[Camera]:
    """Cameras on a horizontal arc around ``target``, all looking at it.

    ``cam00`` sits at the middle of the arc (the held-out test view); the others are
    numbered left to right. Heights alternate by +-0.1 to give a vertical baseline.
    """
    focal = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    K = np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    angles = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, n_cameras))
    middle = n_cameras // 2
    order = [middle] + [k for k in range(n_cameras) if k != middle]
    cams = []
    for idx, k in enumerate(order):
        a = angles[k]
        center = target + radius * np.array([np.sin(a), 0.0, -np.cos(a)])
        center[1] = eye_height + (0.0 if k == middle else 0.1 * (-1) ** k)
        R = look_at(center, target)
        cams.append(Camera(f"cam{idx:02d}", K.copy(), R, -R @ center, width, height))
    return cams


def pixel_rays(cam: Camera, supersample: int = 1) -> np.ndarray:
    """World ray directions with unit camera-z, ``[H*s, W*s, 3]``.

    Sub-pixel ``a`` of pixel (i, j) sits at ``y = i + (a + 0.5)/s - 0.5`` (same in x), so
    ``s = 1`` gives the pixel centres and ``reshape(H, s, W, s)`` groups each pixel's samples.
    """
    s = supersample
    x = (np.arange(cam.width * s) + 0.5) / s - 0.5
    y = (np.arange(cam.height * s) + 0.5) / s - 0.5
    xx, yy = np.meshgrid(x, y)
    d_cam = np.stack([(xx - cam.K[0, 2]) / cam.K[0, 0], (yy - cam.K[1, 2]) / cam.K[1, 1], np.ones_like(xx)], -1)
    return d_cam @ cam.R  # = (R^T d_cam^T)^T


# ----------------------------------------------------------------------------- ray casting


@dataclass
class Hits:
    """Per-ray results on a ray grid ``[R, C]``; set a field to None to stop computing it."""

    depth: np.ndarray  # [R, C] camera z-depth (= ray parameter)
    rgb: np.ndarray | None  # [R, C, 3] shaded colour in [0, 1]
    label: np.ndarray | None  # [R, C] uint8, 0 = static background, k = object k
    flow: np.ndarray | None  # [R, C, 3] world velocity of the surface point, units/s

    def copy(self) -> "Hits":
        dup = lambda a: None if a is None else a.copy()  # noqa: E731
        return Hits(self.depth.copy(), dup(self.rgb), dup(self.label), dup(self.flow))


def cast_static(content: SceneContent, origin: np.ndarray, dirs: np.ndarray, colour: bool = True) -> Hits:
    """Cast the ray grid ``origin [3] + t dirs [R, C, 3]`` against the static surfaces.

    ``colour=False`` skips shading (``rgb`` is None).
    """
    shape = dirs.shape[:2]
    d = dirs.reshape(-1, 3)
    ts = np.stack([s.intersect(origin, d) for s in content.static])  # [S, N]
    idx = np.argmin(ts, axis=0)
    t = ts[idx, np.arange(len(d))]
    if not np.all(np.isfinite(t)):
        raise RuntimeError("synthetic scene is not closed: some rays hit nothing")
    rgb = None
    if colour:
        points = origin + t[:, None] * d
        rgb = np.zeros_like(d)
        for k, surf in enumerate(content.static):
            m = idx == k
            if m.any():
                rgb[m] = surf.shade_points(points[m])
        rgb = rgb.reshape(*shape, 3)
    return Hits(t.reshape(shape), rgb, np.zeros(shape, np.uint8), np.zeros((*shape, 3)))


def _screen_box(cam: Camera, centre: np.ndarray, radius: float, scale: int, shape: tuple[int, int]):
    """Slices of the ray grid (``scale`` rays per pixel) that can see a sphere, or None."""
    corners = centre + radius * np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    cam_pts = corners @ cam.R.T + cam.T
    if np.any(cam_pts[:, 2] <= 1e-3):
        return slice(0, shape[0]), slice(0, shape[1])  # straddles the camera plane: test every ray
    pix = (cam_pts @ cam.K.T)[:, :2] / cam_pts[:, 2:]
    lo = np.floor((pix.min(0) - 1) * scale).astype(int)
    hi = np.ceil((pix.max(0) + 2) * scale).astype(int)
    r0, r1 = np.clip([lo[1], hi[1]], 0, shape[0])
    c0, c1 = np.clip([lo[0], hi[0]], 0, shape[1])
    if r0 >= r1 or c0 >= c1:
        return None
    return slice(r0, r1), slice(c0, c1)


def cast_objects(content: SceneContent, cam: Camera, dirs: np.ndarray, scale: int, time: float,
                 background: Hits) -> Hits:
    """Composite the moving objects at ``time`` (seconds) over ``background``.

    ``dirs [R, C, 3]`` is ``pixel_rays(cam, scale)``; each sphere is only tested against
    the rays inside its projected bounding box.
    """
    out = background.copy()
    origin = cam.center
    for obj in content.objects:
        c = obj.path.position(time)
        box = _screen_box(cam, c, obj.radius, scale, dirs.shape[:2])
        if box is None:
            continue
        d = dirs[box]  # [r, c, 3]
        oc = origin - c
        a = np.einsum("rck,rck->rc", d, d)
        b = d @ oc
        disc = b * b - a * (oc @ oc - obj.radius**2)
        t = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0.0))) / a, np.inf)
        m = (t > 1e-6) & (t < out.depth[box])
        if not m.any():
            continue
        rel = origin - c + t[m][:, None] * d[m]  # hit point relative to the centre
        out.depth[box] = np.where(m, t, out.depth[box])
        if out.rgb is not None:
            normal = rel / obj.radius
            local = normal @ obj.rotation(time)  # object-frame unit vectors
            lon = np.arctan2(local[:, 2], local[:, 0])
            lat = np.arcsin(np.clip(-local[:, 1], -1.0, 1.0))
            albedo = obj.texture.albedo((lon + np.pi) * obj.radius, lat * obj.radius)
            out.rgb[box][m] = shade(albedo, normal)
        if out.label is not None:
            out.label[box][m] = obj.label
        if out.flow is not None:
            out.flow[box][m] = obj.path.velocity(time) + np.cross(obj.angular_velocity(), rel)
    return out
