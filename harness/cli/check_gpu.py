"""``ftgspp check-gpu``: does the gsplat path on this GPU train the model the CPU path trains?

For users with a CUDA GPU (this project's machines have none). Four steps, each printed as
it runs, then a verdict block to paste into an issue:

1. the environment: torch, CUDA device, gsplat (1.5.3 expected: ``pip install -e '.[cuda]'``);
2. parity on the real CUDA kernels: the gsplat adapter against the ``reference`` backend on a
   scene with Gaussians at the near plane, behind the camera, off-screen and saturated
   (image <= 1e-5, gradients <= 1e-4 relative; the same check the CPU suite runs through
   torch stand-ins in ``tests/render/test_gsplat_parity.py``);
3. the quick profile trained with ``backend=gsplat`` (device cuda) and with ``backend=cpu``,
   same scene and seed: their PSNRs should agree within ``PSNR_TOLERANCE`` dB (the runs are
   not bit-identical: different float arithmetic, same model);
4. ``ftgspp bench render`` and ``ftgspp bench train``.

Exit status 0 when every check passes, 1 when one fails, 2 without a CUDA device or gsplat.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from ftgspp.errors import InputError

PSNR_TOLERANCE = 0.5  # dB: about two seed-to-seed SDs of the quick profile (reports/secret5)
IMAGE_TOLERANCE = 1e-5
GRAD_TOLERANCE = 1e-4


def parity_scene(device: torch.device | str, seed: int = 0, n: int = 400) -> dict[str, torch.Tensor]:
    """Random Gaussians plus the cases culling must get right (near plane, behind the camera,
    off-screen, saturated and sub-1/255 opacities), on ``device``."""
    g = torch.Generator().manual_seed(seed)
    z = 1.5 + 4 * torch.rand(n, generator=g)
    xy = (torch.rand(n, 2, generator=g) * 2 - 1) * torch.tensor([0.75, 0.55]) * z[:, None]
    means = torch.cat([xy, z[:, None]], -1)
    means[:4] = torch.tensor([[0.0, 0.0, 0.01], [0.001, 0.0, 0.0099], [0.2, 0.1, -2.0], [0.0, 0.0, 0.0]])
    means[4:10, 0] = torch.tensor([-3.0, -2.2, 2.3, 3.2, -2.5, 2.6]) * means[4:10, 2]
    opacities = 0.05 + 0.9 * torch.rand(n, generator=g)
    opacities[10:16] = torch.tensor([1.0, 0.9995, 0.999, 0.0035, 0.0039, 0.004])
    scene = dict(means=means, quats=torch.randn(n, 4, generator=g), scales=0.02 + 0.12 * torch.rand(n, 3, generator=g),
                 opacities=opacities, colors=torch.rand(n, 3, generator=g))  # fmt: skip
    return {k: v.to(device) for k, v in scene.items()}


def parity(device: torch.device | str, width: int = 96, height: int = 72) -> dict[str, float]:
    """Largest differences between the gsplat adapter and ``reference`` on ``parity_scene``:
    image/alpha/depth (depth relative to its largest value) and each gradient, relative to
    the largest entry of the reference's."""
    from ftgspp.render import gsplat_adapter, render

    scene = parity_scene(device)
    viewmat = torch.eye(4, device=device)
    K = torch.tensor([[78.0, 0.0, (width - 1) / 2], [0.0, 75.0, (height - 1) / 2], [0.0, 0.0, 1.0]], device=device)
    bg = torch.tensor([0.1, 0.3, 0.6], device=device)
    results = {}
    for name in ("gsplat", "reference"):
        leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
        args = (*leaves.values(), viewmat, K, width, height, bg)
        out = gsplat_adapter.render(*args, 0.01) if name == "gsplat" else render(*args, backend="reference")
        g = torch.Generator().manual_seed(5)
        cot = [torch.randn(t.shape, generator=g).to(device) for t in (out.image, out.alpha, out.depth)]
        torch.autograd.backward([out.image, out.alpha, out.depth], cot)
        results[name] = (out, {k: v.grad for k, v in leaves.items()})
    (out, grads), (ref, ref_grads) = results["gsplat"], results["reference"]
    diffs = {"radii_mismatch": float((out.radii != ref.radii).any(-1).sum())}
    for name in ("image", "alpha", "depth"):
        want = getattr(ref, name)
        scale = max(1.0, want.abs().max().item()) if name == "depth" else 1.0
        diffs[name] = (getattr(out, name) - want).abs().max().item() / scale
    for name, want in ref_grads.items():
        diffs[f"grad_{name}"] = ((grads[name] - want).abs().max() / want.abs().max().clamp_min(1e-12)).item()
    return diffs


def parity_passes(diffs: dict[str, float]) -> bool:
    """Whether ``parity``'s differences are within the tolerances of the module docstring."""
    return diffs["radii_mismatch"] == 0 and all(
        v <= (GRAD_TOLERANCE if k.startswith("grad_") else IMAGE_TOLERANCE)
        for k, v in diffs.items() if k != "radii_mismatch"
    )  # fmt: skip


def _ftgspp(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", *args], capture_output=True, text=True)


def _train(scene: Path, out: Path, backend: str, device: str, seed: int) -> dict:
    proc = _ftgspp(["train", "profile=quick", f"data.path={scene}", f"backend={backend}", f"device={device}",
                    f"seed={seed}", f"hydra.run.dir={out}", f"tracking.uri=sqlite:///{out.parent}/mlflow.db"])  # fmt: skip
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        return {"status": "FAILED", "failure": (proc.stderr.strip().splitlines() or ["no output"])[-1]}
    return json.loads(lines[-1])


def main(argv: list[str] | None = None) -> int:
    """Run the checks; print each step and a verdict block. Returns the exit status."""
    parser = argparse.ArgumentParser(prog="ftgspp check-gpu", description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="training seed for both backends (default 0)")
    parser.add_argument("--skip-train", action="store_true", help="parity and bench only (minutes instead of ~15)")
    args = parser.parse_args(argv)
    if not torch.cuda.is_available():
        raise InputError("check-gpu", "no CUDA device (torch.cuda.is_available() is False); the CPU suite checks "
                                      "gsplat parity through torch stand-ins: pytest tests/render/test_gsplat_parity.py")
    try:
        import gsplat
    except ImportError as err:
        raise InputError("check-gpu", f"gsplat is not importable ({err}); pip install -e '.[cuda]'") from err
    lines = [f"torch {torch.__version__}, CUDA {torch.version.cuda}, {torch.cuda.get_device_name(0)}",
             f"gsplat {gsplat.__version__}" + ("" if gsplat.__version__ == "1.5.3" else " (expected 1.5.3)")]
    print("\n".join(lines), flush=True)
    ok = True

    print("[1/3] parity on the CUDA kernels (first use compiles gsplat: several minutes)...", flush=True)
    t0 = time.time()
    diffs = parity(torch.device("cuda"))
    passed = parity_passes(diffs)
    ok &= passed
    worst_grad = max(v for k, v in diffs.items() if k.startswith("grad_"))
    lines.append(f"parity: {'PASS' if passed else 'FAIL'}: image {diffs['image']:.2g}, alpha {diffs['alpha']:.2g}, "
                 f"depth {diffs['depth']:.2g} (<= {IMAGE_TOLERANCE:g}), worst gradient {worst_grad:.2g} "
                 f"(<= {GRAD_TOLERANCE:g}), radii mismatches {int(diffs['radii_mismatch'])}")  # fmt: skip
    print(lines[-1] + f" [{time.time() - t0:.0f} s]", flush=True)

    if not args.skip_train:
        print("[2/3] quick profile, backend=gsplat on cuda and backend=cpu, same seed (about 10-20 min)...", flush=True)
        with tempfile.TemporaryDirectory(prefix="ftgspp-check-gpu-") as tmp:
            scene = Path(tmp) / "studio"
            synth = _ftgspp(["synth", "--out", str(scene), "--preset", "studio", "--seed", "0"])
            if synth.returncode != 0:
                raise InputError("check-gpu", f"scene synthesis failed: {synth.stderr.strip()[-200:]}")
            runs = {b: _train(scene, Path(tmp) / b, b, d, args.seed) for b, d in (("gsplat", "cuda"), ("cpu", "cpu"))}
        psnr = {b: r.get("psnr", math.nan) for b, r in runs.items()}
        failed = [f"{b}: {r.get('failure')}" for b, r in runs.items() if r.get("status") != "FINISHED"]
        delta = psnr["gsplat"] - psnr["cpu"]
        passed = not failed and abs(delta) <= PSNR_TOLERANCE
        ok &= passed
        lines.append(f"quick profile seed {args.seed}: {'PASS' if passed else 'FAIL'}: PSNR gsplat {psnr['gsplat']:.2f}"
                     f" dB, cpu {psnr['cpu']:.2f} dB, difference {delta:+.2f} dB (|.| <= {PSNR_TOLERANCE} dB)"
                     + (f"; {'; '.join(failed)}" if failed else ""))  # fmt: skip
        print(lines[-1], flush=True)

    print("[3/3] bench render and bench train...", flush=True)
    for what in ("render", "train"):
        proc = _ftgspp(["bench", what])
        out = proc.stdout.strip().splitlines()
        shown = "\n  ".join(out[-8:]) if proc.returncode == 0 else f"FAILED: {proc.stderr[-300:]}"
        lines.append(f"bench {what}: {shown}")
        ok &= proc.returncode == 0
        print(lines[-1], flush=True)

    print("\n---- paste into an issue ----\n" + f"ftgspp check-gpu: {'PASS' if ok else 'FAIL'}\n" + "\n".join(lines))
    return 0 if ok else 1
