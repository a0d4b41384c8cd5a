"""EWA projection of 3D Gaussians to 2D image-space Gaussians (plain PyTorch autograd).

Every rasterization backend composites what this module produces, so the projection is
written once, differentiably, and shared. Conventions:

- ``viewmat`` is world-to-camera (OpenCV: x right, y down, z forward), ``K`` is the OpenCV
  intrinsic matrix whose pixel coordinates put pixel (row i, column j) at (x=j, y=i).
- cov3d = R S S^T R^T with R from the (normalised) quaternion (w, x, y, z), S = diag(scales).
- cov2d = J W cov3d W^T J^T + eps2d I, with J the Jacobian of the pinhole projection at the
  camera-space centre, evaluated with x/z and y/z clamped to the image extent plus 30% of
  the half field of view on each side (for a centred principal point: +-1.3 tan(fov/2),
  as in 3DGS and gsplat).
- radius = ceil(3 sqrt(lambda_max(cov2d))) pixels; 0 marks a culled Gaussian: depth <=
  near_plane, det(cov2d) <= 0, or the 3-sigma box entirely outside the image.

Culled Gaussians get zeros in means2d / conics / cov2d and receive exactly zero gradient.

    means2d, conics, depths, radii, cov2d = project(means, quats, scales, viewmat, K, W, H)
"""

from __future__ import annotations

import torch
from torch import Tensor

from ftgspp.render.contract import EPS2D

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
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Project 3D Gaussians into the image.

    Returns ``(means2d [N, 2], conics [N, 3], depths [N], radii [N] int32, cov2d [N, 3])``:
    conics and cov2d are the upper triangles (xx, xy, yy) of the inverse / the 2D covariance
    (low-pass included); depths are the camera-space z of the centres (never masked).
    """
    R = viewmat[:3, :3]  # [3, 3]
    t = viewmat[:3, 3]  # [3]
    p_cam = means @ R.T + t  # [N, 3]
    x, y, z = p_cam.unbind(-1)  # [N] each

    # Sanitise culled entries *before* the divisions so that no inf/NaN reaches autograd.
    in_front = z > near_plane  # [N]
    z_safe = torch.where(in_front, z, torch.ones_like(z))  # [N]

    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    u = x / z_safe  # [N]
    v = y / z_safe
    means2d = torch.stack([fx * u + cx, fy * v + cy], dim=-1)  # [N, 2]

    # Jacobian of (fx x/z + cx, fy y/z + cy), with x/z, y/z clamped (3DGS/gsplat).
    tan_half_x = 0.5 * width / fx
    tan_half_y = 0.5 * height / fy
    u_c = torch.clamp(u, -(cx / fx + 0.3 * tan_half_x), (width - cx) / fx + 0.3 * tan_half_x)
    v_c = torch.clamp(v, -(cy / fy + 0.3 * tan_half_y), (height - cy) / fy + 0.3 * tan_half_y)
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
        mid = 0.5 * (a + c)
        lam_max = mid + torch.sqrt((mid * mid - det).clamp_min(0.0))
        radius = torch.ceil(3.0 * torch.sqrt(lam_max.clamp_min(0.0))).clamp(max=_RADIUS_MAX)
        mx, my = means2d.unbind(-1)
        on_screen = (mx + radius > 0) & (mx - radius < width) & (my + radius > 0) & (my - radius < height)
        keep = valid & on_screen & (radius > 0)
        radii = torch.where(keep, radius, torch.zeros_like(radius)).to(torch.int32)  # [N]

    keep2 = keep.unsqueeze(-1)
    means2d = torch.where(keep2, means2d, torch.zeros_like(means2d))
    conics = torch.where(keep2, conics, torch.zeros_like(conics))
    cov2d = torch.where(keep2, torch.stack([a, b, c], dim=-1), torch.zeros_like(conics))
    return means2d, conics, z, radii, cov2d

