"""Per-camera colour correction: identity at start, learns an affine map, training only."""

import pytest
import torch

from ftgspp.colour_correction import ColorCorrection


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


def test_the_mean_identity_gauge_pins_the_mean_transform_and_keeps_per_camera_differences():
    torch.manual_seed(0)
    free = ColorCorrection(4)
    pinned = ColorCorrection(4, gauge="mean_identity")
    delta, bias = 0.1 + 0.05 * torch.randn(4, 3, 3), 0.2 + 0.01 * torch.randn(4, 3)  # all drifted, plus a bit
    with torch.no_grad():
        for cc in (free, pinned):
            cc.delta.copy_(delta)
            cc.bias.copy_(bias)
    assert free.mean_transform()[0] > 0.2 and pinned.mean_transform() == pytest.approx((0.0, 0.0), abs=1e-6)
    image = torch.rand(5, 6, 3)
    # what the pinned gauge keeps: the cameras' differences from each other
    diff_free = free(image, 0) - free(image, 1)
    diff_pinned = pinned(image, 0) - pinned(image, 1)
    assert torch.allclose(diff_free, diff_pinned, atol=1e-6)
    with pytest.raises(ValueError, match="unknown colour-correction gauge"):
        ColorCorrection(2, gauge="loose")


def test_colour_aligned_psnr_forgives_a_global_colour_transform_only():
    from ftgspp.image_metrics import METRICS, colour_aligned, psnr

    g = torch.rand(1, 16, 16, 3, dtype=torch.float64)
    shifted = (g @ torch.tensor([[0.9, 0.05, 0.0], [0.0, 0.8, 0.1], [0.05, 0.0, 0.95]], dtype=torch.float64) + 0.03)
    assert float(psnr(shifted, g)) < 30 and float(METRICS["psnr_cc"].fn(shifted, g, {})) > 60  # exactly affine
    noisy = g + 0.05 * torch.randn_like(g)
    assert float(METRICS["psnr_cc"].fn(noisy, g, {})) == pytest.approx(float(psnr(colour_aligned(noisy, g), g)))
    assert float(METRICS["psnr_cc"].fn(noisy, g, {})) < 30  # noise is not a colour transform
