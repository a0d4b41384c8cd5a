"""PSNR / SSIM / DSSIM and evaluate_images, checked against scikit-image and scipy.

Oracles: ``skimage.metrics.structural_similarity`` (Gaussian window, sigma 1.5, population
covariance) and ``peak_signal_noise_ratio``; scipy's zero-padded Gaussian filter for the
training-loss SSIM; finite differences (gradcheck) for differentiability.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from ftgspp.errors import InputError
from ftgspp.image_metrics import (
    METRICS,
    dssim,
    evaluate_images,
    main_metrics,
    psnr,
    read_image,
    ssim,
    ssim_same,
)

LPIPS_REF_DIR = Path(__file__).resolve().parent / "assets" / "lpips_ref"  # images, provenance, licence

BASE_KEYS = ["psnr", "psnr_cc", "ssim1", "ssim2", "dssim1", "dssim2"]
LPIPS_KEYS = ["lpips_alex", "lpips_vgg", "lpips_alex_01", "lpips_vgg_01"]


def natural_image(seed: int, h: int = 61, w: int = 74) -> np.ndarray:
    """Smooth random colour field plus a hard edge and a disk, float64 [h, w, 3] in [0, 1]."""
    rng = np.random.default_rng(seed)
    img = np.stack([gaussian_filter(rng.standard_normal((h, w)), 5.0) for _ in range(3)], axis=-1)
    img = (img - img.min()) / (img.max() - img.min())
    yy, xx = np.mgrid[:h, :w]
    img[:, : w // 3] = 0.8 * img[:, : w // 3] + 0.2  # vertical step edge
    img[(yy - h / 2) ** 2 + (xx - 2 * w / 3) ** 2 < (h / 5) ** 2] = rng.random(3)  # flat disk
    return img


def distortions(img: np.ndarray, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [
        np.clip(img + 0.05 * rng.standard_normal(img.shape), 0.0, 1.0),  # noise
        gaussian_filter(img, sigma=(1.2, 1.2, 0)),  # blur
        np.roll(img, shift=(1, 2), axis=(0, 1)),  # misalignment
        np.clip(0.9 * img + 0.08, 0.0, 1.0),  # exposure change
    ]


def reference_pairs() -> list[tuple[np.ndarray, np.ndarray]]:
    pairs = []
    for seed in range(2):
        img = natural_image(seed)
        pairs += [(d, img) for d in distortions(img, seed)]
    ref = read_image(LPIPS_REF_DIR / "ex_ref.png").double().numpy()
    for name in ("ex_p0.png", "ex_p1.png"):
        pairs.append((read_image(LPIPS_REF_DIR / name).double().numpy(), ref))
    return pairs


def sk_ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    return structural_similarity(a, b, channel_axis=-1, data_range=data_range, gaussian_weights=True,
                                 sigma=1.5, use_sample_covariance=False)


@pytest.mark.parametrize("data_range", [1.0, 2.0])
def test_ssim_matches_skimage(data_range: float):
    pairs = reference_pairs()
    for a, b in pairs:
        expected = sk_ssim(a, b, data_range)
        # float64 agrees to rounding (measured ~4e-15); float32 to its own precision (~1e-5)
        for dtype, tol in ((torch.float64, 1e-12), (torch.float32, 5e-5)):
            got = float(ssim(torch.from_numpy(a).to(dtype), torch.from_numpy(b).to(dtype), data_range))
            assert abs(got - expected) < tol, (dtype, got, expected)
    batch_a = torch.from_numpy(np.stack([a for a, _ in pairs[:4]]))
    batch_b = torch.from_numpy(np.stack([b for _, b in pairs[:4]]))
    got = ssim(batch_a, batch_b, data_range)  # [B]
    expected = [sk_ssim(a, b, data_range) for a, b in pairs[:4]]
    np.testing.assert_allclose(got.numpy(), expected, rtol=0, atol=1e-12)


def test_psnr_matches_skimage():
    for a, b in reference_pairs():
        expected = peak_signal_noise_ratio(b, a, data_range=1.0)
        assert abs(float(psnr(torch.from_numpy(a), torch.from_numpy(b))) - expected) < 1e-6


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])  # float32: the Numba kernels
def test_training_ssim_matches_zero_padded_gaussian_filter(dtype):
    a, b = reference_pairs()[0]

    def blur(x):  # zero padding, 11 taps (truncate 3.5 at sigma 1.5 -> radius 5)
        return gaussian_filter(x, sigma=(1.5, 1.5, 0), mode="constant", cval=0.0, truncate=3.5)

    mx, my = blur(a), blur(b)
    vx, vy, vxy = blur(a * a) - mx**2, blur(b * b) - my**2, blur(a * b) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    expected = (((2 * mx * my + c1) * (2 * vxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))).mean()
    got = ssim_same(torch.from_numpy(a).to(dtype), torch.from_numpy(b).to(dtype))
    assert got.dtype == dtype and abs(float(got) - expected) < (1e-6 if dtype == torch.float64 else 2e-6)


def test_ssim_variants_are_differentiable():
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(12, 13, 3, dtype=torch.float64, generator=gen, requires_grad=True)
    b = torch.rand(12, 13, 3, dtype=torch.float64, generator=gen)
    # fast_mode: finite differences along random directions instead of the full Jacobian
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,), fast_mode=True)
    assert torch.autograd.gradcheck(lambda x: ssim_same(x, b), (a,), fast_mode=True)


def test_identical_images():
    img = torch.from_numpy(natural_image(3))
    values = evaluate_images(img, img.clone())
    assert values["psnr"] == float("inf")
    assert abs(values["ssim1"] - 1.0) < 1e-12 and abs(values["ssim2"] - 1.0) < 1e-12
    assert abs(values["dssim1"]) < 1e-12 and abs(values["dssim2"]) < 1e-12


def test_evaluate_images_averages_per_frame_and_names_keys():
    pairs = reference_pairs()[:3]
    pred = torch.from_numpy(np.stack([a for a, _ in pairs])).float()
    gt = torch.from_numpy(np.stack([b for _, b in pairs])).float()
    values = evaluate_images(pred, gt)
    assert list(values) == BASE_KEYS  # no LPIPS keys without LPIPS models
    for r, key in ((1.0, "ssim1"), (2.0, "ssim2")):
        per_frame = [sk_ssim(p.double().numpy(), g.double().numpy(), r) for p, g in zip(pred, gt)]
        assert abs(values[key] - np.mean(per_frame)) < 1e-4
        assert abs(values[f"d{key}"] - (1 - values[key]) / 2) < 1e-12
    per_frame_psnr = [peak_signal_noise_ratio(g.double().numpy(), p.double().numpy(), data_range=1.0) for p, g in zip(pred, gt)]
    assert abs(values["psnr"] - np.mean(per_frame_psnr)) < 1e-4
    assert abs(float(dssim(pred[0], gt[0])) - (1 - sk_ssim(pred[0].double().numpy(), gt[0].double().numpy(), 1.0)) / 2) < 1e-4
    with pytest.raises(KeyError):
        evaluate_images(pred, gt, names=["lpips_vgg"])


def test_evaluate_images_blurs_each_frame_once_and_matches_ssim_and_dssim_bit_for_bit(monkeypatch):
    import ftgspp.image_metrics as m

    pairs = reference_pairs()[:2]
    pred = torch.from_numpy(np.stack([a for a, _ in pairs])).float()
    gt = torch.from_numpy(np.stack([b for _, b in pairs])).float()
    alone = {}  # each metric on its own, as before the ranges shared their moments
    for r in (1.0, 2.0):
        alone[f"ssim{r:g}"] = float(np.mean([float(ssim(p.double(), g.double(), r)) for p, g in zip(pred, gt)]))
        alone[f"dssim{r:g}"] = float(np.mean([float(dssim(p.double(), g.double(), r)) for p, g in zip(pred, gt)]))
    calls = []
    real = m._blur
    monkeypatch.setattr(m, "_blur", lambda *a, **k: calls.append(1) or real(*a, **k))
    for names in (["dssim1", "ssim1", "dssim2"], ["ssim2", "dssim2"], ["ssim1", "ssim2", "dssim1", "dssim2"], ["psnr"]):
        calls.clear()
        values = evaluate_images(pred, gt, names=names)
        assert len(calls) == (len(pred) if names != ["psnr"] else 0)  # one blur per frame for every range
        assert all(values[k] == alone[k] for k in names if k in alone)  # the same bits as each alone


def test_evaluate_images_with_lpips_has_every_convention(lpips_models):
    img = torch.from_numpy(natural_image(4)).float()
    values = evaluate_images(img, img.flip(0), lpips=lpips_models)
    assert list(values) == list(METRICS) == BASE_KEYS + LPIPS_KEYS
    assert all(np.isfinite(v) and v > 0 for k, v in values.items() if k in LPIPS_KEYS)


def test_metrics_cli_json_and_table(lpips_weights, capsys):
    a, b = str(LPIPS_REF_DIR / "ex_ref.png"), str(LPIPS_REF_DIR / "ex_p1.png")
    assert main_metrics([a, b, "--json", "--weights", str(lpips_weights)]) == 0
    values = json.loads(capsys.readouterr().out.strip())
    assert list(values) == BASE_KEYS + LPIPS_KEYS
    assert round(values["lpips_vgg"], 3) == 0.422
    assert main_metrics([a, b, "--weights", str(lpips_weights)]) == 0
    table = capsys.readouterr().out
    assert all(key in table for key in BASE_KEYS + LPIPS_KEYS) and "3DGS convention" in table


def test_metrics_cli_without_weights_prints_a_note(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FTGSPP_LPIPS_WEIGHTS", str(tmp_path))
    a, b = str(LPIPS_REF_DIR / "ex_ref.png"), str(LPIPS_REF_DIR / "ex_p0.png")
    assert main_metrics([a, b]) == 0
    out = capsys.readouterr().out
    assert "lpips_vgg" not in out and "ssim2" in out
    assert f"LPIPS weights not found in {tmp_path}; run `ftgspp weights fetch`" in out


def test_metrics_cli_input_errors(tmp_path: Path):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((32, 48, 3), np.uint8))
    with pytest.raises(InputError, match="not found"):
        main_metrics([str(tmp_path / "missing.png"), str(small)])
    with pytest.raises(InputError, match="does not match"):
        main_metrics([str(LPIPS_REF_DIR / "ex_ref.png"), str(small)])
    (tmp_path / "junk.png").write_text("not an image")
    with pytest.raises(InputError, match="cannot be read"):
        main_metrics([str(tmp_path / "junk.png"), str(small)])


def test_read_image_is_rgb(tmp_path: Path):
    bgr = np.zeros((12, 12, 3), np.uint8)
    bgr[..., 2] = 255  # red in OpenCV's BGR order
    cv2.imwrite(str(tmp_path / "red.png"), bgr)
    img = read_image(tmp_path / "red.png")
    assert img.shape == (12, 12, 3) and float(img[..., 0].min()) == 1.0 and float(img[..., 2].max()) == 0.0


def test_library_does_not_import_hydra_or_mlflow():
    code = "import sys, ftgspp.image_metrics, ftgspp.lpips; print(any(m in sys.modules for m in ('hydra', 'mlflow')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
