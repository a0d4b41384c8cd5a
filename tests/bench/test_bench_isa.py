"""Benchmarks name the vector ISA they ran with, and run for another CPU target in a child
process with its own kernel cache, refusing a target this host cannot execute."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from ftgspp.bench import cli, isa
from harness.cli.ftgspp_cmd import main as ftgspp_main

AVX2_HOST = {"sse2": True, "sse4.2": True, "avx": True, "avx2": True, "fma": True, "avx512f": False}


def test_widest_extension_of_a_feature_map() -> None:
    assert isa.widest(AVX2_HOST) == "avx2"
    assert isa.widest({**AVX2_HOST, "avx512f": True}) == "avx512f"
    assert isa.widest({"sse2": True}) == "sse2"


def test_host_isa_names_the_host_the_kernels_and_torch(monkeypatch: pytest.MonkeyPatch) -> None:
    import llvmlite.binding as ll
    import torch

    monkeypatch.delenv("NUMBA_CPU_NAME", raising=False)
    info = isa.host_isa()
    assert info["host_cpu"] == ll.get_host_cpu_name() == info["numba_target"]
    assert info["host_isa"] == info["numba_isa"] == isa.ISA_NAMES[isa.widest(isa._host_features())]
    assert info["torch_kernels"] == torch.backends.cpu.get_cpu_capability()
    monkeypatch.setenv("NUMBA_CPU_NAME", "generic")
    assert isa.host_isa()["numba_isa"] == "SSE2"
    assert "Numba kernels for generic (SSE2)" in isa.describe(isa.host_isa())


def test_a_target_the_host_lacks_is_one_line_and_exit_2(monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(isa, "_host_features", lambda: dict(AVX2_HOST))
    called = []
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: called.append(a))
    with pytest.raises(SystemExit) as exc:
        ftgspp_main(["bench", "render", "--target", "skylake-avx512"])
    assert exc.value.code == 2 and not called  # refused before any child starts
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "AVX-512" in err[0] and "--target" in err[0]
    with pytest.raises(SystemExit):
        ftgspp_main(["bench", "train", "--target", "pentium-mmx"])
    assert "unknown CPU target" in capsys.readouterr().err


def test_the_child_compiles_for_the_target_in_its_own_cache(monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(isa, "_host_features", lambda: dict(AVX2_HOST))
    seen = {}

    def fake_run(argv, env, **kw):
        seen.update(argv=argv, env=env)
        result = {"n": 5, "n_visible": 5, "width": 8, "height": 6, "repeats": 1, "ratios": {}, "yardstick": None,
                  "backends": {"cpu": {"fwd_ms": 1.0, "fwd_bwd_ms": 2.0}}, "load_average": [0.0, 0.0],
                  "cpu_count": 2, "numba_compile_s": {}, "isa": {"host_cpu": "h", "host_isa": "AVX2",
                  "numba_target": env["NUMBA_CPU_NAME"], "numba_isa": "AVX2", "torch_kernels": "AVX2"}}  # fmt: skip
        return subprocess.CompletedProcess(argv, 0, stdout="noise\n" + json.dumps(result) + "\n", stderr="")

    monkeypatch.setattr(isa.subprocess, "run", fake_run)
    assert cli.main(["render", "--n", "5", "--target", "haswell", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["target"] == "haswell" and out["isa"]["numba_target"] == "haswell"
    env = seen["env"]
    assert env["NUMBA_CPU_NAME"] == "haswell" and env["NUMBA_CPU_FEATURES"] == ""  # the target's own features
    assert env["NUMBA_CACHE_DIR"] and env[isa.CHILD_FLAG] == "1"
    assert env["ATEN_CPU_CAPABILITY"] == "avx2" and env["ONEDNN_MAX_CPU_ISA"] == "AVX2"  # torch as on that CPU
    assert seen["argv"][-5:] == ["ftgspp.bench", "render", "--n", "5", "--json"]  # no --target in the child
    assert cli.main(["render", "--n", "5", "--target=haswell"]) == 0
    assert "Numba kernels for haswell (AVX2)" in capsys.readouterr().out  # the table names it


def test_a_target_caps_torch_at_its_own_isa() -> None:
    assert isa.target_environment("znver3")["ATEN_CPU_CAPABILITY"] == "avx2"
    assert isa.target_environment("generic") == {"NUMBA_CPU_NAME": "generic", "NUMBA_CPU_FEATURES": "",
                                                 "ATEN_CPU_CAPABILITY": "default", "ONEDNN_MAX_CPU_ISA": "SSE41"}
    assert isa.target_environment("sapphirerapids")["ATEN_CPU_CAPABILITY"] == "avx512"
    if isa.widest(isa._host_features()) in ("avx2", "avx512f"):  # torch on this host takes the cap
        env = dict(os.environ, **isa.target_environment("haswell"))
        code = "import torch; print(torch.backends.cpu.get_cpu_capability())"
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        assert out.stdout.strip() == "AVX2"
