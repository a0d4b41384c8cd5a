"""EWA projection: geometry against independent computations, culling, gradients."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ftgspp.render.contract import EPS2D
from ftgspp.render.project import covariance_3d, project, quat_to_rotmat

W, H = 64, 48
F = 50.0


def intrinsics(dtype=torch.float64) -> torch.Tensor:
    return torch.tensor([[F, 0, 31.5], [0, F * 1.1, 23.5], [0, 0, 1]], dtype=dtype)


def look_viewmat(dtype=torch.float64) -> torch.Tensor:
    """A non-trivial world-to-camera transform (rotation + translation)."""
    v = torch.eye(4, dtype=dtype)
    v[:3, :3] = torch.from_numpy(Rotation.from_euler("xyz", [0.2, -0.3, 0.1]).as_matrix())
    v[:3, 3] = torch.tensor([0.1, -0.2, 0.3], dtype=dtype)
    return v


def world_from_camera(p_cam: torch.Tensor, viewmat: torch.Tensor) -> torch.Tensor:
    return (p_cam - viewmat[:3, 3]) @ viewmat[:3, :3]


def random_gaussians(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    lo = torch.tensor([-0.8, -0.6, 2.0], dtype=torch.float64)
    p_cam = lo + torch.rand(n, 3, generator=g, dtype=torch.float64) * torch.tensor([1.6, 1.2, 3.0], dtype=torch.float64)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64) * 2.0  # deliberately not unit
    scales = torch.rand(n, 3, generator=g, dtype=torch.float64) * 0.1 + 0.02
    return world_from_camera(p_cam, look_viewmat()), quats, scales


def test_rotation_and_covariance_match_scipy() -> None:
    _, quats, scales = random_gaussians(20)
    q = quats.numpy()
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is scalar-last
    np.testing.assert_allclose(quat_to_rotmat(quats).numpy(), R, atol=1e-12)
    expected = R @ np.apply_along_axis(np.diag, 1, scales.numpy() ** 2) @ R.transpose(0, 2, 1)
    np.testing.assert_allclose(covariance_3d(quats, scales).numpy(), expected, atol=1e-12)


def test_means_depths_and_conics() -> None:
    means, quats, scales = random_gaussians(30)
    viewmat, K = look_viewmat(), intrinsics()
    means2d, conics, depths, radii, cov2d = project(means, quats, scales, viewmat, K, W, H)
    p_cam = means @ viewmat[:3, :3].T + viewmat[:3, 3]
    uv = (p_cam @ K.T)[:, :2] / p_cam[:, 2:3]  # homogeneous pinhole, independent of project()
    torch.testing.assert_close(means2d, uv)
    torch.testing.assert_close(depths, p_cam[:, 2])
    assert (radii > 0).all() and radii.dtype == torch.int32
    cov = torch.stack([cov2d[:, 0], cov2d[:, 1], cov2d[:, 1], cov2d[:, 2]], -1).reshape(-1, 2, 2)
    inv = torch.stack([conics[:, 0], conics[:, 1], conics[:, 1], conics[:, 2]], -1).reshape(-1, 2, 2)
    torch.testing.assert_close(cov @ inv, torch.eye(2, dtype=torch.float64).expand(30, 2, 2))
    # without opacities, gsplat's widest box: 3.33 standard deviations of each axis
    sd = np.sqrt(np.stack([cov2d[:, 0].numpy(), cov2d[:, 2].numpy()], -1))
    np.testing.assert_array_equal(radii.numpy(), np.ceil(3.33 * sd).astype(np.int32))


def test_opacity_aware_radii_hold_every_pixel_alpha_reaches_one_255th() -> None:
    """gsplat's box: every pixel where alpha >= 1/255 lies inside it, and it is one pixel
    short of the tightest such box at most (checked on a dense sub-pixel grid)."""
    means, quats, scales = random_gaussians(40, seed=3)
    opac = torch.linspace(0.003, 1.0, 40, dtype=torch.float64)
    means2d, conics, _, radii, _ = project(means, quats, scales, look_viewmat(), intrinsics(), W, H, opacities=opac)
    offs = torch.linspace(-40, 40, 1601, dtype=torch.float64)  # 0.05 px steps
    dx, dy = torch.meshgrid(offs, offs, indexing="xy")
    for k in range(40):
        a, b, c = conics[k].tolist()
        alpha = opac[k] * torch.exp(-0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy)
        hit = alpha >= 1 / 255
        if radii[k, 0] == 0:
            assert opac[k] < 1 / 255 or not hit.any()
            continue
        rx, ry = radii[k].tolist()
        assert dx[hit].abs().max() <= rx and dy[hit].abs().max() <= ry
        assert dx[hit].abs().max() > rx - 1.05 and dy[hit].abs().max() > ry - 1.05
    assert radii[0].tolist() == [0, 0] and (radii[1:] > 0).all()  # 0.003 < 1/255 is culled


def pinhole(p_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    x, y, z = p_cam[..., 0], p_cam[..., 1], p_cam[..., 2]
    return np.stack([K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]], -1)


def test_cov2d_is_the_linearised_projection() -> None:
    """J from central finite differences of the pinhole map, and a Monte-Carlo estimate."""
    means, quats, scales = random_gaussians(5, seed=1)
    scales = scales * 0.2  # small Gaussians (sigma / z ~ 1%): linearisation is accurate
    viewmat, K = look_viewmat(), intrinsics()
    _, _, _, _, cov2d = project(means, quats, scales, viewmat, K, W, H)
    R = viewmat[:3, :3].numpy()
    p_cam = (means @ viewmat[:3, :3].T + viewmat[:3, 3]).numpy()
    cov_cam = R @ covariance_3d(quats, scales).numpy() @ R.T
    rng = np.random.default_rng(0)
    for i in range(5):
        h = 1e-6
        Kn = K.numpy()
        J = np.stack([(pinhole(p_cam[i] + h * e, Kn) - pinhole(p_cam[i] - h * e, Kn)) / (2 * h) for e in np.eye(3)], -1)
        lin = J @ cov_cam[i] @ J.T
        got = np.array([[cov2d[i, 0], cov2d[i, 1]], [cov2d[i, 1], cov2d[i, 2]]]) - EPS2D * np.eye(2)
        np.testing.assert_allclose(got, lin, rtol=1e-6, atol=1e-9)
        samples = rng.multivariate_normal(p_cam[i], cov_cam[i], size=200_000)
        mc = np.cov(pinhole(samples, K.numpy()).T)
        np.testing.assert_allclose(got, mc, atol=0.02 * np.abs(got).max())


def test_jacobian_uses_clamped_direction_outside_the_field_of_view() -> None:
    viewmat, K = torch.eye(4, dtype=torch.float64), intrinsics()
    # x/z = 1.2 lies beyond (W - cx)/fx + 0.3 * 0.5 W/fx = 0.65 + 0.192; huge so it still reaches the image.
    p = torch.tensor([[2.4, 0.0, 2.0]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    scales = torch.tensor([[2.0, 0.3, 0.5]], dtype=torch.float64)
    _, _, _, radii, cov2d = project(p, quats, scales, viewmat, K, W, H)
    assert (radii[0] > 0).all()
    u_lim = (W - 32.0) / F + 0.3 * 0.5 * W / F  # gsplat's principal point: cx + 0.5
    fx, z = F, 2.0
    J = np.array([[fx / z, 0, -fx * u_lim / z], [0, F * 1.1 / z, 0.0]])
    expected = J @ np.diag(scales[0].numpy() ** 2) @ J.T + EPS2D * np.eye(2)
    np.testing.assert_allclose(cov2d[0].numpy(), [expected[0, 0], expected[0, 1], expected[1, 1]], rtol=1e-12)


def test_culling_and_zero_gradients_for_culled() -> None:
    viewmat, K = torch.eye(4, dtype=torch.float64), intrinsics()
    p = torch.tensor(
        [
            [0.0, 0.0, 2.0],  # visible
            [0.0, 0.0, -2.0],  # behind the camera
            [0.0, 0.0, 0.0],  # at the camera centre
            [0.0, 0.0, 0.0099],  # just short of the near plane
            [40.0, 0.0, 2.0],  # far off to the side: its 3-sigma box misses the image
            [0.0, 0.0, 0.01],  # exactly on the near plane: visible (gsplat culls z < near only)
        ],
        dtype=torch.float64,
        requires_grad=True,
    )
    quats = torch.tensor([[1.0, 0.2, 0.0, 0.1]] * 6, dtype=torch.float64, requires_grad=True)
    scales = torch.full((6, 3), 0.01, dtype=torch.float64, requires_grad=True)
    means2d, conics, depths, radii, cov2d = project(p, quats, scales, viewmat, K, W, H)
    visible = (radii > 0).all(-1)
    assert visible.tolist() == [True, False, False, False, False, True]
    (means2d.sum() + conics.sum() + cov2d.sum()).backward()
    for t in (p, quats, scales):
        assert torch.isfinite(t.grad).all()
        assert (t.grad[1:5] == 0).all()
        assert t.grad[0].abs().sum() > 0


def test_gradcheck() -> None:
    means, quats, scales = random_gaussians(4, seed=2)
    viewmat, K = look_viewmat(), intrinsics()

    def f(m, q, s):
        means2d, conics, depths, _, cov2d = project(m, q, s, viewmat, K, W, H)
        return means2d, conics, depths, cov2d

    inputs = tuple(t.clone().requires_grad_() for t in (means, quats, scales))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_isotropic_gaussian_on_axis() -> None:
    """On the optical axis, J = diag(f/z) exactly: sigma_px^2 = (f s / z)^2 + eps2d."""
    K = torch.tensor([[F, 0, 31.0], [0, F, 23.0], [0, 0, 1]], dtype=torch.float64)
    means = torch.tensor([[0.0, 0.0, 4.0]], dtype=torch.float64)
    quats = torch.tensor([[0.3, 0.5, -0.2, 0.7]], dtype=torch.float64)  # irrelevant: isotropic
    scales = torch.full((1, 3), 0.1, dtype=torch.float64)
    _, conics, _, radii, cov2d = project(means, quats, scales, torch.eye(4, dtype=torch.float64), K, W, H)
    var = (F * 0.1 / 4.0) ** 2 + EPS2D
    torch.testing.assert_close(cov2d[0], torch.tensor([var, 0.0, var], dtype=torch.float64))
    torch.testing.assert_close(conics[0], torch.tensor([1 / var, 0.0, 1 / var], dtype=torch.float64))
    assert radii[0].tolist() == [math.ceil(3.33 * math.sqrt(var))] * 2
