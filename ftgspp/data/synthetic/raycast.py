"""A vectorised numpy ray caster for the synthetic scenes (``ftgspp synth``).

``cast_static`` finds the nearest static surface of every ray of a grid and shades it;
``cast_objects`` composites the moving spheres at one time over that background, with
their labels and scene flow. Ray grids come from ``rig.pixel_rays`` (unit
camera-z directions, so the hit parameter is the camera z-depth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.data.synthetic.geometry import SceneContent
from ftgspp.data.synthetic.textures import shade


@dataclass
class Hits:
    """Per-ray results on a ray grid ``[R, C]``; set a field to None to stop computing it."""

    depth: np.ndarray  # [R, C] camera z-depth (= ray parameter)
    rgb: np.ndarray | None  # [R, C, 3] shaded colour in [0, 1]
    label: np.ndarray | None  # [R, C] uint8, 0 = static background, k = object k
    flow: np.ndarray | None  # [R, C, 3] world velocity of the surface point, units/s

    def copy(self) -> "Hits":
        """An independent copy (arrays duplicated)."""
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


def _ray_box(origin: np.ndarray, dirs: np.ndarray, centre: np.ndarray, radius: float):
    """Slices of the ray grid ``dirs [R, C, 3]`` whose rays can hit a sphere, or None."""
    to_centre = centre - origin
    dist = np.linalg.norm(to_centre)
    if dist <= radius * 1.01:
        return slice(0, dirs.shape[0]), slice(0, dirs.shape[1])  # the camera is (nearly) inside it
    cos_ray = (dirs @ to_centre) / (np.linalg.norm(dirs, axis=-1) * dist)  # [R, C]
    rows, cols = np.nonzero(cos_ray >= np.cos(np.arcsin(radius / dist)) - 1e-3)
    if len(rows) == 0:
        return None
    return slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1)


def cast_objects(content: SceneContent, cam: Camera, dirs: np.ndarray, scale: int, time: float,
                 background: Hits, box_from_rays: bool = False) -> Hits:
    """Composite the moving objects at ``time`` (seconds) over ``background``.

    ``dirs [R, C, 3]`` is ``pixel_rays(cam, scale)``; each sphere is only tested against
    the rays inside its projected bounding box. Rays through a lens (any grid of unit
    camera-z rays from ``cam.center``): ``box_from_rays`` finds the box from the rays instead.
    """
    out = background.copy()
    origin = cam.center
    for obj in content.objects:
        if not obj.present(time):
            continue
        c = obj.path.position(time)
        if box_from_rays:
            box = _ray_box(origin, dirs, c, obj.radius)
        else:
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
            if obj.flicker:
                albedo = np.clip(albedo * obj.appearance(time, local), 0.0, 1.0)
            out.rgb[box][m] = shade(albedo, normal)
        if out.label is not None:
            out.label[box][m] = obj.label
        if out.flow is not None:
            out.flow[box][m] = obj.path.velocity(time) + np.cross(obj.angular_velocity(), rel)
    return out
