"""Per-camera colour correction: identity at start, learns an affine map, training only."""

import torch

from ftgspp.color import ColorCorrection


def test_identity_at_start():
    cc = ColorCorrection(4)
    img = torch.rand(5, 7, 3)
    for cam in range(4):
        assert torch.equal(cc(img, cam), img)
    assert cc.regularizer().item() == 0.0
    torch.testing.assert_close(cc.matrices(), torch.eye(3).expand(4, 3, 3))


def test_fits_a_known_affine_shift():
    """Gradient descent on the correction recovers a true per-camera affine shift."""
    g = torch.Generator().manual_seed(0)
    true_m = torch.eye(3) + 0.05 * torch.randn(3, 3, generator=g)
    true_b = 0.02 * torch.randn(3, generator=g)
    img = torch.rand(16, 16, 3, generator=g)
    target = img @ true_m + true_b
    cc = ColorCorrection(2)
    opt = torch.optim.Adam(cc.parameters(), lr=1e-2)
    for _ in range(800):
        opt.zero_grad()
        ((cc(img, 1) - target) ** 2).mean().backward()
        opt.step()
    torch.testing.assert_close(cc.matrices()[1], true_m, atol=2e-3, rtol=0)
    torch.testing.assert_close(cc.bias[1].detach(), true_b, atol=2e-3, rtol=0)
    torch.testing.assert_close(cc.matrices()[0], torch.eye(3))  # other cameras untouched
