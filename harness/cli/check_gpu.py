"""``ftgspp check-gpu``: does the gsplat path on this GPU train the model the CPU path trains, how fast?

For a CUDA machine with gsplat 1.5.3 (``pip install -e '.[cuda]'``), or the device machine through
``scripts/gpu_check.sh`` and the offline kit (``make gpu-kit``; docs/gpu.md). Steps, each printed
as it runs, then one summary block to paste into an issue (also ``OUT/summary.txt``; every figure
in ``OUT/results.json``, the runs' metrics and logs in ``OUT/runs.tar.gz``):

1. the environment: torch, CUDA, GPU, driver, gsplat, and where each package comes from;
2. gsplat's CUDA code compiled once (later processes load it from ``TORCH_EXTENSIONS_DIR``);
3. parity on the real kernels (``harness.run.gpu_parity``): image, alpha, depth, gradients, radii,
   culled Gaussians; the bench rasterizer; relocation against gsplat's ``relocate``;
4. the quick profile of FreeTimeGS and STGS with ``backend=gsplat`` (cuda) and ``backend=cpu``, same
   scene and seed: |dPSNR| <= ``PSNR_TOLERANCE`` (the runs are the same model in different float
   arithmetic, not the same bits); the CPU runs train while gsplat compiles;
5. ``ftgspp bench render`` / ``bench train`` at 5k Gaussians (every backend, both methods) and at
   500k (render at paper resolution: gsplat and cpu; train: gsplat, both methods);
6. the paper profile (FreeTimeGS++, 500k Gaussians) on a paper-resolution synthetic scene for the
   time left: iterations per second, peak GPU memory.

``--budget S`` bounds the whole (``scripts/gpu_check.sh``: 480 s from its start); a step that no
longer fits is skipped and the summary says so. ``--dry-run`` needs no GPU (``gpu_dry_run``).
Exit status 0 when every check that ran passed, 1 when one failed, 2 without a CUDA device or gsplat.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tarfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import torch

from ftgspp.errors import InputError
from harness.cli.gpu_plan import (
    MODELS, REPO, Check, _cmd, bench_commands, cpu_run_threads, json_line, paper_overrides, quick_overrides,
    synth_args, tail,
)  # fmt: skip
from harness.run.gpu_parity import parity, parity_passes, parity_scene  # noqa: F401  (the tests import them here)

PSNR_TOLERANCE = 0.5  # dB: about two seed-to-seed SDs of the quick profile (reports/secret5)


def train_quick(chk: Check, scene: Path, model: str, backend: str, seed: int, cap: float) -> dict[str, Any]:
    """One quick run through ``ftgspp train``; its JSON result or {status: FAILED, failure}."""
    name = f"quick_{model}_{backend}"
    args = ["train", *quick_overrides(scene, model, backend, seed), f"hydra.run.dir={chk.work / 'runs' / name}"]
    env = None
    if backend == "cpu":  # both CPU runs start beside nvcc: with torch's threads capped alone, each took
        n = str(cpu_run_threads())  # 16 Numba threads on the H200's machine and trained at 3.3 it/s (2026-11-29)
        env = {"NUMBA_NUM_THREADS": n, "OMP_NUM_THREADS": n}
    rc, text = chk.run(_cmd(args), f"{name}.log", cap, env)
    result = json_line(text)
    if rc != 0 or result is None:
        return {"status": "FAILED", "failure": "timed out" if rc == 124 else tail(text)}
    return result


def environment(chk: Check) -> None:
    """Record Python, torch, CUDA, GPU, driver, gsplat and the commit; compile for this GPU only."""
    import platform

    import gsplat

    props = torch.cuda.get_device_properties(0)
    driver = "?"
    if smi := shutil.which("nvidia-smi"):
        proc = subprocess.run([smi, "--query-gpu=driver_version", "--format=csv,noheader"], capture_output=True, text=True)
        driver = proc.stdout.strip() if proc.returncode == 0 else driver
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    line = (f"python {platform.python_version()}, torch {torch.__version__}, CUDA {torch.version.cuda}, {props.name} "
            f"(sm_{props.major}{props.minor}, {props.total_memory / 2**30:.0f} GiB), driver {driver}, gsplat "
            f"{gsplat.__version__}{'' if gsplat.__version__ == '1.5.3' else ' (expected 1.5.3)'}, commit "
            f"{commit.stdout.strip() or 'unknown (no .git)'}, {time.strftime('%Y-%m-%d %H:%M %Z')}")  # fmt: skip
    chk.record("environment", line, None, {"torch_file": torch.__file__, "gsplat_file": gsplat.__file__})
    os.environ.setdefault("TORCH_CUDA_ARCH_LIST", f"{props.major}.{props.minor}")  # compile for this GPU only
    os.environ.setdefault("MAX_JOBS", str(os.cpu_count() or 4))


def compile_gsplat(chk: Check) -> bool:
    """Import gsplat's CUDA extension (JIT-compiled on first use, then cached); False if it fails."""
    t0 = time.time()
    try:
        from gsplat.cuda import _backend

        ok = _backend._C is not None
        error = "" if ok else "gsplat found no CUDA toolkit (nvcc): it disabled itself"
    except Exception as exc:  # the compiler's error is in the message
        ok, error = False, f"{type(exc).__name__}: {exc}"
    seconds = time.time() - t0
    if not ok:
        print(error[-6000:], flush=True)
    chk.record("compile", f"gsplat CUDA extension: {'PASS' if ok else 'FAIL'}: {seconds:.0f} s"
               + ("" if ok else f": {tail(error, 2)[:300]}"), ok, {"seconds": seconds, "error": error[-4000:]})  # fmt: skip
    return ok


def quick_lines(chk: Check, model: str, seed: int, runs: dict[str, dict[str, Any]]) -> None:
    """The |dPSNR| verdict of one method's gsplat and cpu quick runs."""
    psnr = {b: r.get("psnr", float("nan")) for b, r in runs.items()}
    failed = [f"{b}: {r.get('failure')}" for b, r in runs.items() if r.get("status") != "FINISHED"]
    delta = psnr["gsplat"] - psnr["cpu"]
    passed = not failed and abs(delta) <= PSNR_TOLERANCE
    its = ", ".join(f"{b} {r.get('iters_per_second', float('nan')):.1f} it/s" for b, r in runs.items())
    chk.record(f"quick {model}", f"quick {model} seed {seed}: {'PASS' if passed else 'FAIL'}: PSNR gsplat "
               f"{psnr['gsplat']:.2f} dB, cpu {psnr['cpu']:.2f} dB, difference {delta:+.2f} dB (|.| <= "
               f"{PSNR_TOLERANCE} dB); {its}" + (f"; {'; '.join(failed)}" if failed else ""), passed, runs)  # fmt: skip


def bench_line(key: str, r: dict[str, Any]) -> str:
    """One line of a bench result: ms per render or iterations per second per backend."""
    if "render" in key:
        t = r["backends"]
        parts = [f"{b} {v['fwd_ms']:.2f}/{v['fwd_bwd_ms']:.2f} ms" for b, v in t.items()]
        if "gsplat" in t and "cpu" in t:
            parts.append(f"cpu/gsplat {t['cpu']['fwd_bwd_ms'] / t['gsplat']['fwd_bwd_ms']:.1f}x (fwd+bwd)")
        return f"{key} ({r['width']}x{r['height']}, fwd/fwd+bwd): " + ", ".join(parts)
    parts = [f"{b} {t['iters_per_second']:.1f} it/s" for b, t in r["backends"].items()]
    return f"{key} ({r['width']}x{r['height']}): " + ", ".join(parts)


def run_benches(chk: Check) -> None:
    for key, args in bench_commands().items():
        if not chk.fits(key, 45):
            continue
        cmd = _cmd(args, "harness.run.gpu_speed") if key == "bench render 500k" else _cmd(args)
        rc, text = chk.run(cmd, f"{key.replace(' ', '_')}.log", 150)
        result = json_line(text)
        if rc != 0 or result is None:
            chk.record(key, f"{key}: FAIL: {'timed out' if rc == 124 else tail(text)}", False)
        else:
            chk.record(key, bench_line(key, result), None, result)


def paper_run(chk: Check, synth: subprocess.Popen | None) -> None:
    """The paper profile on the paper-size scene for the time left."""
    if synth is None or not chk.fits("paper", 60):
        return
    try:
        rc = synth.wait(timeout=chk.timeout(120))
    except subprocess.TimeoutExpired:
        chk.record("paper", "paper: SKIPPED: the paper-size scene was not ready in time", None)
        return
    if rc != 0:
        chk.record("paper", "paper: FAIL: the paper-size scene could not be made", False)
        return
    seconds = chk.left() - 25 if chk.budget > 0 else 120.0
    args = ["train", "--seconds", f"{seconds:.0f}", "--out", str(chk.work / "runs" / "paper"),
            *paper_overrides(chk.work / "paper_scene")]  # fmt: skip
    rc, text = chk.run(_cmd(args, "harness.run.gpu_speed"), "paper.log", seconds + 20)
    r = json_line(text)
    if rc != 0 or r is None:
        chk.record("paper", f"paper: FAIL: {'timed out' if rc == 124 else tail(text)}", False)
        return
    memory = (f", peak GPU memory {r['peak_gpu_allocated_gib']:.1f} GiB allocated, {r['peak_gpu_reserved_gib']:.1f} GiB"
              " reserved" if r["peak_gpu_allocated_gib"] is not None else "")  # fmt: skip
    chk.record("paper", f"paper ftgspp {r['n_gaussians']} Gaussians {r['width']}x{r['height']} x {r['n_cameras']} cams:"
               f" {r['iters_per_second']:.1f} it/s over {r['iterations_done']} iterations of {r['iterations_planned']}"
               f" (init {r['init_seconds']:.0f} s){memory}", None, r)  # fmt: skip


def finish(chk: Check) -> int:
    """End the children still running; write summary.txt, results.json and runs.tar.gz into the
    output folder; print the block. Returns the exit status."""
    chk.closed = True
    for proc in chk.procs:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    head = f"ftgspp check-gpu: {'PASS' if chk.ok else 'FAIL'} ({time.time() - chk.started:.0f} s"
    head += f" of a {chk.budget:.0f} s budget)" if chk.budget > 0 else ")"
    block = "\n".join([f"---- {head} ----", *chk.lines, "----"])
    chk.out.mkdir(parents=True, exist_ok=True)
    (chk.out / "summary.txt").write_text(block + "\n")
    (chk.out / "results.json").write_text(json.dumps({"ok": chk.ok, **chk.results}, indent=1, default=str) + "\n")
    with tarfile.open(chk.out / "runs.tar.gz", "w:gz") as tar:  # logs and metrics, no checkpoints or renders
        for p in sorted(chk.work.rglob("*")):
            if p.is_file() and (p.suffix in (".log", ".json", ".yaml") or p.name == "train.log"):
                tar.add(p, arcname=p.relative_to(chk.work).as_posix())
    print("\n" + block, flush=True)
    shutil.rmtree(chk.work, ignore_errors=True)  # scenes and checkpoints: gigabytes at paper size
    return 0 if chk.ok else 1


def guarded(chk: Check, key: str, fn: Any, *args: Any) -> Any:
    """``fn(*args)``; an exception fails step ``key`` and the check goes on with the next step."""
    try:
        return fn(*args)
    except Exception as exc:
        chk.record(key, f"{key}: FAIL: {type(exc).__name__}: {str(exc)[:300]}", False)
        return None


def parity_step(chk: Check) -> None:
    from harness.run.gpu_parity import describe, suite

    results = suite("cuda")
    for name, line in zip(results, describe(results).splitlines()):
        chk.record(f"parity {name}", line, bool(results[name].get("passed")), results[name])


def quick_step(chk: Check, pool: ThreadPoolExecutor, cpu_future: Any, scene: Path, seed: int) -> None:
    """The gsplat quick runs of both methods at once, then each against its CPU run."""
    gsplat_runs = {m: pool.submit(train_quick, chk, scene, m, "gsplat", seed, 300) for m in MODELS}
    try:
        cpu = cpu_future.result(timeout=chk.timeout(600))
    except Exception as exc:  # the scene or a CPU run: both methods' comparisons fail, gsplat's runs still count
        cpu = {m: {"status": "FAILED", "failure": f"{type(exc).__name__}: {str(exc)[:200]}"} for m in MODELS}
    for m in MODELS:
        quick_lines(chk, m, seed, {"gsplat": gsplat_runs[m].result(), "cpu": cpu[m]})


def real_run(chk: Check, args: argparse.Namespace) -> int:
    """Steps 1-6 of the module docstring; the quick scene's CPU runs and the paper-size scene are
    made in the background while gsplat compiles."""
    scene = chk.work / "studio"
    pool = ThreadPoolExecutor(6)  # the CPU runs and their parent thread, the gsplat runs

    def cpu_runs() -> dict[str, dict[str, Any]]:  # the quick scene, then both methods on the CPU at once
        rc, text = chk.run(_cmd(synth_args(scene, paper=False)), "synth.log", 120)
        if rc != 0:
            raise RuntimeError(f"scene synthesis failed: {tail(text)}")
        futures = {m: pool.submit(train_quick, chk, scene, m, "cpu", args.seed, 400) for m in MODELS}
        return {m: f.result() for m, f in futures.items()}

    cpu_future = None if args.skip_train else pool.submit(cpu_runs)
    paper_synth = None if args.skip_train else chk.start(_cmd(synth_args(chk.work / "paper_scene", True)), "synth_paper.log")
    chk.step("1/6 environment")
    guarded(chk, "environment", environment, chk)
    chk.step("2/6 gsplat's CUDA code (the first time: minutes)")
    if compile_gsplat(chk):
        chk.step("3/6 parity on the CUDA kernels")
        guarded(chk, "parity", parity_step, chk)
        if cpu_future is not None and chk.fits("quick", 60):
            chk.step("4/6 quick profile, gsplat on cuda and cpu, same seed")
            guarded(chk, "quick", quick_step, chk, pool, cpu_future, scene, args.seed)
        chk.step("5/6 benches")
        guarded(chk, "benches", run_benches, chk)
        chk.step("6/6 the paper profile for the time left")
        guarded(chk, "paper", paper_run, chk, paper_synth)
    code = finish(chk)  # ends the children, so the pool's threads return
    pool.shutdown(wait=True, cancel_futures=True)
    return code


def main(argv: list[str] | None = None) -> int:
    """Run the checks; print each step and a summary block. Returns the exit status."""
    parser = argparse.ArgumentParser(prog="ftgspp check-gpu", description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="training seed for both backends (default 0)")
    parser.add_argument("--skip-train", action="store_true", help="parity and benches only")
    parser.add_argument("--out", type=Path, default=Path("outputs/check-gpu"), help="where the summary goes")
    parser.add_argument("--budget", type=float, default=0, help="seconds for the whole check (0: no limit, and"
                        " the paper profile trains 120 s)")  # fmt: skip
    parser.add_argument("--started", type=float, default=None, help="when the budget started (epoch seconds)")
    parser.add_argument("--dry-run", action="store_true", help="no GPU: up to the first CUDA call (gpu_dry_run)")
    parser.add_argument("--kit", type=Path, default=None, help="the kit folder (gpu_check.sh: .whl)")
    parser.add_argument("--kit-site", type=Path, default=None, help="where gpu_check.sh installed the kit")
    args = parser.parse_args(argv)
    started = args.started or time.time()
    if args.dry_run:
        from harness.cli.gpu_dry_run import dry_run

        chk = Check(args.out, args.budget, started)
        dry_run(chk, args)
        return finish(chk)
    if not torch.cuda.is_available():
        raise InputError("check-gpu", "no CUDA device (torch.cuda.is_available() is False); the CPU suite checks "
                                      "gsplat parity through torch stand-ins: pytest tests/render/test_gsplat_parity.py")
    try:
        import gsplat  # noqa: F401
    except ImportError as err:
        raise InputError("check-gpu", f"gsplat is not importable ({err}); pip install -e '.[cuda]'") from err
    return real_run(Check(args.out, args.budget, started), args)
