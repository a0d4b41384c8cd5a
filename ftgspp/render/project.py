"""EWA projection of 3D Gaussians to 2D image-space Gaussians (plain PyTorch autograd).

Every rasterization backend composites what this module produces, so the projection is
written once, differentiably, and shared. Conventions:

- ``viewmat`` is world-to-camera (OpenCV: x right, y down, z forward), ``K`` is the OpenCV
  intrinsic matrix whose pixel coordinates put pixel (row i, column j) at (x=j, y=i).
- cov3d = R S S^T R^T with R from the (normalised) quaternion (w, x, y, z), S = diag(scales).
- cov2d = J W cov3d W^T J^T + eps2d I, with J the Jacobian of the pinhole projection at the
  camera-space centre, evaluated with x/z and y/z clamped to the image extent plus 30% of
  the half field of view on each side, measured from gsplat's principal point (cx + 0.5).
- radii [N, 2] per axis and opacity-aware, culling as gsplat 1.5.3 does (the rules are
  stated once in ``contract.py``); without ``opacities`` the extent is 3.33 sigmas.

Culled Gaussians get zeros in means2d / conics / cov2d and receive exactly zero gradient.

    means2d, conics, depths, radii, cov2d = project(means, quats, scales, viewmat, K, W, H)
"""

from __future__ import annotations

import torch
from torch import Tensor

from ftgspp.render.contract import ALPHA_MIN, EPS2D, FAR_PLANE, PIXEL_OFFSET, RADIUS_EXTEND

# Radii are clamped here before the int32 cast; a Gaussian this large covers any image.
_RADIUS_MAX = 1.0e6


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices from quaternions (w, x, y, z), normalised here. [N, 4] -> [N, 3, 3]."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(q.shape[:-1] + (3, 3))


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World-space covariances R S S^T R^T. quats [N, 4], scales [N, 3] -> [N, 3, 3]."""
    m = quat_to_rotmat(quats) * scales.unsqueeze(-2)  # [N, 3, 3] = R S
    return m @ m.transpose(-1, -2)


def project(
    means: Tensor,  # [N, 3] world
    quats: Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: Tensor,  # [N, 3] activated (positive)
    viewmat: Tensor,  # [4, 4] world-to-camera
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = EPS2D,
    opacities: Tensor | None = None,  # [N] in [0, 1]: opacity-aware radii and culling
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Project 3D Gaussians into the image.

    Returns ``(means2d [N, 2], conics [N, 3], depths [N], radii [N, 2] int32, cov2d [N, 3])``:
    conics and cov2d are the upper triangles (xx, xy, yy) of the inverse / the 2D covariance
    (low-pass included); depths are the camera-space z of the centres (never masked).
    """
    R = viewmat[:3, :3]  # [3, 3]
    t = viewmat[:3, 3]  # [3]
    p_cam = means @ R.T + t  # [N, 3]
    x, y, z = p_cam.unbind(-1)  # [N] each

    # Sanitise culled entries *before* the divisions so that no inf/NaN reaches autograd.
    in_front = (z >= near_plane) & (z <= FAR_PLANE)  # [N]
    z_safe = torch.where(in_front, z, torch.ones_like(z))  # [N]

    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u = x / z_safe  # [N]
    v = y / z_safe
    means2d = torch.stack([fx * u + cx, fy * v + cy], dim=-1)  # [N, 2]

    # Jacobian of (fx x/z + cx, fy y/z + cy), with x/z, y/z clamped as gsplat does, around
    # its principal point (cx + 0.5, cy + 0.5).
    lo_x, hi_x, lo_y, hi_y = tangent_limits(K, width, height)
    u_c = torch.clamp(u, lo_x, hi_x)
    v_c = torch.clamp(v, lo_y, hi_y)
    zero = torch.zeros_like(z)
    J = torch.stack(
        [
            torch.stack([fx / z_safe, zero, -fx * u_c / z_safe], dim=-1),
            torch.stack([zero, fy / z_safe, -fy * v_c / z_safe], dim=-1),
        ],
        dim=-2,
    )  # [N, 2, 3]

    cov_cam = R @ covariance_3d(quats, scales) @ R.T  # [N, 3, 3]
    cov = J @ cov_cam @ J.transpose(-1, -2)  # [N, 2, 2]
    a = cov[:, 0, 0] + eps2d
    b = 0.5 * (cov[:, 0, 1] + cov[:, 1, 0])
    c = cov[:, 1, 1] + eps2d
    det = a * c - b * b  # [N]

    valid = in_front & (det > 0)
    det_safe = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=-1)  # [N, 3]

    with torch.no_grad():
        if opacities is None:
            extend = torch.full_like(a, RADIUS_EXTEND)
            bright = torch.ones_like(valid)
        else:
            o = opacities.detach().to(a.dtype)
            bright = o >= ALPHA_MIN
            ratio = torch.where(bright, o / torch.tensor(ALPHA_MIN, dtype=a.dtype), torch.ones_like(o))
            extend = torch.sqrt(2.0 * torch.log(ratio)).clamp(max=RADIUS_EXTEND)
        rx = torch.ceil(extend * torch.sqrt(a.clamp_min(0.0))).clamp(max=_RADIUS_MAX)
        ry = torch.ceil(extend * torch.sqrt(c.clamp_min(0.0))).clamp(max=_RADIUS_MAX)
        gx, gy = (means2d + PIXEL_OFFSET).unbind(-1)  # gsplat's pixel coordinates
        on_screen = (gx + rx > 0) & (gx - rx < width) & (gy + ry > 0) & (gy - ry < height)
        keep = valid & bright & on_screen & ((rx > 0) | (ry > 0))
        radii = torch.where(keep.unsqueeze(-1), torch.stack([rx, ry], -1), 0.0).to(torch.int32)  # [N, 2]

    keep2 = keep.unsqueeze(-1)
    means2d = torch.where(keep2, means2d, torch.zeros_like(means2d))
    conics = torch.where(keep2, conics, torch.zeros_like(conics))
    cov2d = torch.where(keep2, torch.stack([a, b, c], dim=-1), torch.zeros_like(conics))
    return means2d, conics, z, radii, cov2d


def tangent_limits(K: Tensor, width: int, height: int) -> tuple[float, float, float, float]:
    """Clamp window (lo_x, hi_x, lo_y, hi_y) of x/z and y/z for the Jacobian, as gsplat's
    ``persp_proj`` computes it (its principal point is ours + 0.5), in the dtype of ``K``."""
    k = K.detach().cpu()
    fx, fy = k[0, 0], k[1, 1]
    cx, cy = k[0, 2] + PIXEL_OFFSET, k[1, 2] + PIXEL_OFFSET
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    lims = (-(cx / fx + 0.3 * tan_x), (width - cx) / fx + 0.3 * tan_x,
            -(cy / fy + 0.3 * tan_y), (height - cy) / fy + 0.3 * tan_y)  # fmt: skip
    return tuple(float(v) for v in lims)
