"""Portable determinism: the same config gives the same bits under environments that mimic
other x86-64 machines; the default mode is shown to depend on them (so the test can fail).

Each run is a fresh ``ftgspp train`` process (the environment is read when torch, NumPy,
OpenCV and oneDNN load), smoke profile on the tiny scene, diagnostics off; a portable run
trains in a child process with the portable environment, whose output the command shows.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch
from test_trainer import params

from ftgspp.runtime.determinism import determinism_domain, isa_class, portable_environment

# Outer environments that mimic other machines: torch kernel dispatch, oneDNN ISA caps, no
# AVX-512/AVX2 in NumPy and OpenCV, thread counts, Numba kernels compiled for the baseline ISA.
MACHINES = {
    "native": {},
    "baseline": {"ATEN_CPU_CAPABILITY": "default"},
    "no_avx512": {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL", "OPENCV_CPU_DISABLE": "AVX512-SKX",
                  "ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2"},
    "one_thread": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"},
    # Numba kernels compiled for the x86-64 baseline (SSE2, no AVX) instead of this host's ISA
    "sse2_numba": {"NUMBA_CPU_NAME": "generic"},
}
TIMING = {"train_seconds", "iters_per_second", "peak_rss_mb", "init_seconds", "eval_seconds",
          "eval_lpips_seconds", "diagnostics_seconds"}


def train_in(env_extra: dict[str, str], mode: str, scene: Path, out: Path) -> tuple[dict, dict, dict]:
    env = {k: v for k, v in os.environ.items() if k not in {"FTGSPP_DETERMINISM"}}
    env.update(env_extra)
    r = subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", "train", "profile=smoke", f"data.path={scene}",
                        "progress=false", "init.keyframe_stride=3", "diagnostics=false", f"determinism={mode}",
                        f"hydra.run.dir={out}"], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    if mode == "portable":  # trained in a child process: its output reached the command's stderr
        child_output = (out / "dispatch_child.log").read_text()
        assert "init:" in child_output and child_output in r.stderr
    params = torch.load(out / "gaussians.pt", weights_only=True)
    metrics = {k: v for k, v in json.loads((out / "metrics.json").read_text()).items() if k not in TIMING}
    return params, metrics, json.loads((out / "determinism.json").read_text())


@pytest.fixture(scope="module")
def runs(tiny_scene_dir: Path, tmp_path_factory) -> dict[tuple[str, str], tuple[dict, dict, dict]]:
    root = tmp_path_factory.mktemp("determinism")
    jobs = [("portable", name) for name in MACHINES] + [("default", name) for name in ("native", "baseline")]
    # two processes at a time (each trains on one thread); the slow one, which compiles the
    # Numba kernels for the baseline ISA, starts first
    jobs.sort(key=lambda job: job[1] != "sse2_numba")
    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {job: pool.submit(train_in, MACHINES[job[1]], job[0], tiny_scene_dir, root / f"{job[0]}_{job[1]}")
                   for job in jobs}
        return {job: f.result() for job, f in futures.items()}


def same_bits(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_portable_mode_gives_identical_parameters_and_metrics_on_every_machine(runs):
    params, metrics, domain = runs["portable", "native"]
    for name in MACHINES:
        p, m, d = runs["portable", name]
        assert same_bits(p, params), name
        assert m == metrics, name
        assert d["id"] == domain["id"] and d["torch_cpu_capability"] == "DEFAULT" and d["mode"] == "portable"


def test_default_mode_depends_on_the_kernel_dispatch(runs):
    native, baseline = runs["default", "native"], runs["default", "baseline"]
    assert not same_bits(native[0], baseline[0]), "torch's kernel dispatch changes the bits in default mode"
    assert native[2]["id"] != baseline[2]["id"], "and the recorded domain says so"
    assert native[2]["mode"] == "default"


def test_portable_environment_pins_every_dispatching_library():
    env = portable_environment({"ATEN_CPU_CAPABILITY": "avx512", "PATH": "/bin"})
    assert env["ATEN_CPU_CAPABILITY"] == "default" and env["MKL_CBWR"] == "COMPATIBLE"
    assert env["FTGSPP_DETERMINISM"] == "portable" and env["PATH"] == "/bin"
    assert "X86_V4" in env["NPY_DISABLE_CPU_FEATURES"] and "AVX2" in env["OPENCV_CPU_DISABLE"]
    assert "-FMA" in env["GLIBC_TUNABLES"] and env["NUMBA_DISABLE_INTEL_SVML"] == "1"  # libm the kernels call
    assert "NUMBA_CPU_NAME" not in env  # Numba stays on the host ISA (7x faster rasterizer, same bits)


def test_domain_records_what_the_bits_depend_on():
    d = determinism_domain("default")
    for key in ("cpu_model", "isa_class", "torch_cpu_capability", "onednn", "mkl_cbwr", "torch_threads",
                "numba_threads", "versions", "id"):
        assert d[key], key
    assert "torch 2.13.0" in d["versions"] and "numba" in d["versions"] and "opencv" in d["versions"]
    assert isa_class({"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl", "avx2", "fma"}) == "x86-64-v4"
    assert isa_class({"avx2", "fma", "bmi2", "movbe", "sse4_2"}) == "x86-64-v3"


def test_a_portable_run_from_a_default_process_trains_in_a_pinned_child(tiny_scene_dir, tiny_scene, tmp_path,
                                                                         monkeypatch, capsys):
    from test_trainer import small_cfg

    from ftgspp.trainer import train

    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "avx2")  # this process's own setting must not leak in
    result = train(small_cfg(tiny_scene_dir, tmp_path, determinism="portable", iterations=6, diagnostics=False),
                   tiny_scene)
    domain = json.loads((tmp_path / "determinism.json").read_text())
    assert result.status == "FINISHED" and domain["mode"] == "portable"
    assert domain["torch_cpu_capability"] == "DEFAULT" and domain["onednn"] == "off"
    child_output = (tmp_path / "dispatch_child.log").read_text()
    assert "init:" in child_output and child_output in capsys.readouterr().err  # streamed as it came


def test_a_failing_child_shows_its_output_and_its_last_line_in_the_error(tiny_scene_dir, tiny_scene, tmp_path,
                                                                          capsys):
    from test_trainer import small_cfg

    from ftgspp.trainer import train

    cfg = small_cfg(tiny_scene_dir, tmp_path / "run", dispatch="baseline", background=[0.0])  # fails to render
    with pytest.raises(RuntimeError, match="failed in its child process: .*background must have shape"):
        train(cfg, tiny_scene)
    child_output = (tmp_path / "run" / "dispatch_child.log").read_text()
    assert "Traceback" in child_output and child_output in capsys.readouterr().err


def test_a_dispatch_run_trains_in_a_child_with_that_kernel_set(tiny_scene_dir, tiny_scene, tmp_path):
    """dispatch=baseline: the child runs torch's baseline kernels; the parent gets its metrics,
    params (which render stage ran), loss curve, artifacts and determinism domain, and the bits
    differ from the native run."""
    from test_trainer import small_cfg
    from test_trainer_parts import Recorder

    from ftgspp.trainer import train

    native = train(small_cfg(tiny_scene_dir, tmp_path / "native", diagnostics=False), tiny_scene)

    class Tags(Recorder):
        def __init__(self) -> None:
            super().__init__()
            self.tags: dict = {}
            self.params: dict = {}
            self.artifacts: list = []

        def log_params(self, params):
            self.params.update(params)

        def set_tags(self, tags):
            self.tags.update(tags)

        def log_artifact(self, path, artifact_path=None):
            self.artifacts.append((path, artifact_path))

    rec = Tags()
    other = train(small_cfg(tiny_scene_dir, tmp_path / "baseline", diagnostics=False, dispatch="baseline"),
                  tiny_scene, rec)
    assert other.status == "FINISHED" and rec.tags["determinism.torch_cpu_capability"] == "DEFAULT"
    assert any("loss" in m for _, m in rec.metrics) and any(where == "renders" for _, where in rec.artifacts)
    assert rec.params["render_stage"] == "fused" and int(rec.params["n_gaussians_init"]) > 0  # FreeTimeGS on cpu
    a, b = params(tmp_path / "native"), params(tmp_path / "baseline")
    assert not same_bits(a, b) and abs(other.metrics["psnr"] - native.metrics["psnr"]) < 0.5


def test_an_input_error_in_the_child_is_raised_in_the_parent(tiny_scene_dir, tiny_scene, tmp_path):
    from test_trainer import small_cfg

    from ftgspp.errors import InputError
    from ftgspp.trainer import train

    cfg = small_cfg(tiny_scene_dir, tmp_path, determinism="portable")
    cfg.strategy.relocation = "teleport"  # rejected when the child builds its training state
    with pytest.raises(InputError, match="relocation"):
        train(cfg, tiny_scene)


@pytest.mark.parametrize("over, key", [({"dispatch": "sse9"}, "dispatch"),
                                       ({"dispatch": "avx2", "determinism": "portable"}, "dispatch")])
def test_bad_dispatch_is_one_line(over, key, tiny_scene_dir, tiny_scene, tmp_path):
    from test_trainer import small_cfg

    from ftgspp.errors import InputError
    from ftgspp.trainer import train

    with pytest.raises(InputError, match=key):
        train(small_cfg(tiny_scene_dir, tmp_path, **over), tiny_scene)
