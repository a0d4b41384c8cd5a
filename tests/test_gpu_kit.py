"""The GPU check's offline kit and its dry run, on a CPU machine.

The device machine has no network and CPython 3.12 (docs/gpu.md): ``make gpu-kit`` downloads the
wheels the check needs there, and ``scripts/gpu_check.sh --dry-run`` runs the check up to its
first CUDA call with gsplat's CUDA ops replaced by the torch stand-ins. These tests build the kit
once into a temporary folder -- about 7 MB from PyPI (gsplat 1.5.3, hydra-core, omegaconf,
diptest; the antlr4 runtime's sdist, built here) plus the LPIPS-Alex weights from the cache the
suite's fixtures fill -- and run the dry run (about 30 s on 2 cores).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from harness.cli import gpu_kit

ROOT = Path(__file__).resolve().parents[1]
KIT_NAMES = {"gsplat", "hydra-core", "omegaconf", "antlr4-python3-runtime", "diptest"}


@pytest.fixture(scope="module")
def kit(tmp_path_factory, lpips_weights: Path) -> Path:
    dest = tmp_path_factory.mktemp("kit") / ".whl"
    gpu_kit.build(dest)
    return dest


def fake_wheel(folder: Path, name: str, version: str, requires: tuple[str, ...] = ()) -> Path:
    """A pure-Python wheel holding only its metadata."""
    dist = f"{name.replace('-', '_')}-{version}"
    path = folder / f"{dist}-py3-none-any.whl"
    meta = "\n".join(["Metadata-Version: 2.1", f"Name: {name}", f"Version: {version}",
                      *(f"Requires-Dist: {r}" for r in requires)]) + "\n"  # fmt: skip
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(f"{dist}.dist-info/METADATA", meta)
        z.writestr(f"{dist}.dist-info/WHEEL", "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
        z.writestr(f"{dist}.dist-info/RECORD", "")
    return path


def test_the_kit_resolves_offline_for_the_device_and_fits(kit: Path) -> None:
    assert gpu_kit.check(kit) == []
    manifest = json.loads((kit / "kit.json").read_text())
    assert manifest["python"] == "3.12"
    assert {w["name"] for w in manifest["wheels"].values()} == KIT_NAMES
    assert not KIT_NAMES & gpu_kit.DEVICE_HAS  # nothing the device has, torch above all
    wheels = sorted(p.name for p in kit.glob("*.whl"))
    assert all(re.search(r"-(py3-none-any|cp312-cp312-manylinux[\w.]*x86_64)\.whl$", w) for w in wheels), wheels
    assert (kit / "lpips" / "lpips_alex.pt").is_file()
    size = gpu_kit.kit_bytes(kit) / 2**20
    assert size <= gpu_kit.LIMIT_MIB
    assert f"kit size: {size:.1f} MiB (limit 48 MiB)" in gpu_kit.report(kit)


def test_the_kit_check_finds_a_missing_requirement_a_device_package_and_a_changed_file(kit: Path, tmp_path) -> None:
    bad = tmp_path / "kit"
    shutil.copytree(kit, bad)
    next(bad.glob("antlr4*.whl")).unlink()  # omegaconf and hydra-core need it; the device lacks it
    fake_wheel(bad, "torch", "2.13.0")  # would replace the device's torch
    with open(next(bad.glob("gsplat-*.whl")), "ab") as f:
        f.write(b"\0")
    problems = "\n".join(gpu_kit.check(bad))
    assert "needs antlr4-python3-runtime==4.9.*: neither in the kit nor on the device" in problems
    assert "torch: the device has it; the kit must not replace it" in problems
    assert "gsplat-1.5.3-py3-none-any.whl: missing or changed since the kit was built" in problems
    assert "not the ones kit.json lists" in problems


def test_the_kit_check_knows_the_devices_versions(kit: Path, tmp_path) -> None:
    """A wheel whose requirement the device's torch 2.11 does not meet is a problem."""
    bad = tmp_path / "kit"
    shutil.copytree(kit, bad)
    fake_wheel(bad, "needs-new-torch", "1.0", ("torch>=2.12",))
    assert any("needs torch>=2.12: the device has 2.11.0" in p for p in gpu_kit.check(bad))


def test_the_dry_run_reaches_the_first_cuda_call_with_the_kit(kit: Path, tmp_path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), "--dry-run", "--kit", str(kit), "--out",
                           str(out), "--python", sys.executable], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "torch untouched" in proc.stdout and "installing the kit offline" in proc.stdout
    summary = (out / "summary.txt").read_text()
    assert summary.startswith("---- ftgspp check-gpu: PASS")
    assert "first CUDA call reached: gsplat _C.projection_ewa_3dgs_fused_fwd, answered by the torch stand-in" in summary
    results = json.loads((out / "results.json").read_text())
    assert results["ok"] and results["parity render"]["passed"] and results["parity relocation"]["passed"]
    origins = dict(line.split(": ", 1) for line in results["imports"]["result"])
    for name in ("gsplat", "hydra-core", "omegaconf", "antlr4-python3-runtime"):  # pure Python: loaded from the kit
        assert origins[name] == "kit", (name, origins[name])
    assert origins["torch"] == "device" and "mlflow" not in origins and "pandas" not in origins
    assert results["smoke stg"]["result"]["status"] == "FINISHED"
    # what the device tool brings back: at most 8 files, plain names
    files = sorted(p.name for p in out.rglob("*"))
    assert len(files) <= 8 and all(re.fullmatch(r"[\w.-]+", f) for f in files), files
    assert {"summary.txt", "results.json", "log.txt", "runs.tar.gz"} <= set(files)


def test_the_import_check_names_a_package_the_device_lacks(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    from harness.cli.gpu_dry_run import import_origins

    site = tmp_path / "site-packages"
    (site / "nodevicepkg").mkdir(parents=True)
    (site / "nodevicepkg" / "__init__.py").write_text("")
    (site / "nodevicepkg-1.0.dist-info").mkdir()
    (site / "nodevicepkg-1.0.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: nodevicepkg\nVersion: 1.0\n")
    (site / "nodevicepkg-1.0.dist-info" / "top_level.txt").write_text("nodevicepkg\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delitem(sys.modules, "nodevicepkg", raising=False)
    __import__("nodevicepkg")
    try:
        lines, problems = import_origins(kit={"hydra-core"}, kit_site=tmp_path / "empty-kit")
    finally:
        sys.modules.pop("nodevicepkg", None)
    assert "nodevicepkg: imported by the check, neither on the device nor in the kit" in problems
    assert "numpy: device" in lines
    # hydra-core is the kit's, not installed in its site: another Python's wheel, not a failure
    assert not any(p.startswith("hydra-core") for p in problems)


def test_the_parity_suite_fails_on_a_planted_half_pixel_and_a_wrong_relocation(monkeypatch: pytest.MonkeyPatch) -> None:
    from tests.render.gsplat_standins import install

    import ftgspp.render.gsplat_adapter as adapter
    import ftgspp.strategy.relocate as relocate
    from harness.run import gpu_parity

    install(monkeypatch)
    assert all(r["passed"] for r in gpu_parity.suite("cpu").values())
    monkeypatch.setattr(adapter, "PIXEL_OFFSET", 0.0)  # gsplat's pixel centres taken for ours
    real = relocate.mcmc_opacity_scale
    monkeypatch.setattr(relocate, "mcmc_opacity_scale", lambda *a: (real(*a)[0], real(*a)[1] * 1.001))
    results = gpu_parity.suite("cpu")
    assert not results["render"]["passed"] and results["render"]["image"] > 1e-3
    assert not results["relocation"]["passed"] and results["relocation"]["params"] > 1e-5


def test_a_deadline_ends_a_training_run_and_its_rate_is_measured(tiny_scene_dir: Path, tmp_path) -> None:
    from harness.run.gpu_speed import timed_training

    r = timed_training(["profile=smoke", f"data.path={tiny_scene_dir}", "backend=reference", "device=cpu",
                        "diagnostics=false", "eval_lpips=[]"], tmp_path / "run", seconds=0)  # fmt: skip
    assert r["status"] == "deadline" and r["iterations_done"] == 10  # the first logged step (smoke: every 10)
    assert r["iters_per_second"] > 0 and r["n_gaussians"] == 300 and r["init_seconds"] >= 0
    assert not (tmp_path / "run" / "metrics.json").exists()  # stopped before evaluation


def test_the_quick_verdict_and_a_skipped_step(tmp_path) -> None:
    from harness.cli.check_gpu import Check, finish, quick_lines

    chk = Check(tmp_path / "out", budget=100, started=0)  # long past: nothing fits
    assert not chk.fits("bench render 5k", 45)
    quick_lines(chk, "ftgs", 0, {"gsplat": {"status": "FINISHED", "psnr": 30.2}, "cpu": {"status": "FINISHED", "psnr": 30.0}})
    quick_lines(chk, "stg", 0, {"gsplat": {"status": "FINISHED", "psnr": 29.0}, "cpu": {"status": "FINISHED", "psnr": 30.0}})
    assert chk.results["bench render 5k"]["passed"] is None and "SKIPPED" in chk.lines[0]
    assert chk.results["quick ftgs"]["passed"] and not chk.results["quick stg"]["passed"]
    assert finish(chk) == 1
    assert "difference -1.00 dB" in (tmp_path / "out" / "summary.txt").read_text()


def test_the_cpu_quick_runs_are_capped_to_a_quarter_of_the_cores(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """On the H200 both uncapped CPU runs took 16 Numba threads beside nvcc and trained at 3.3 it/s;
    each now gets a quarter of the cores, through torch's ``threads`` and Numba's variable."""
    import harness.cli.check_gpu as check_gpu

    calls = []

    class Recorder:
        work = tmp_path

        def run(self, cmd, log, cap, env=None):
            calls.append((cmd, env))
            return 1, ""

    import harness.cli.gpu_plan as gpu_plan

    monkeypatch.setattr(gpu_plan.os, "cpu_count", lambda: 16)
    for backend in ("cpu", "gsplat"):
        check_gpu.train_quick(Recorder(), tmp_path / "scene", "ftgs", backend, 0, 10)
    (cpu_cmd, cpu_env), (gs_cmd, gs_env) = calls
    assert "threads=4" in cpu_cmd and cpu_env == {"NUMBA_NUM_THREADS": "4", "OMP_NUM_THREADS": "4"}
    assert gs_env is None and not any(a.startswith("threads=") for a in gs_cmd)
    assert check_gpu.cpu_run_threads(2) == 1
