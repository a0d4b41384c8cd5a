"""``ftgspp bench render``: its JSON line and table, and the parsing of its compile probe.

Timings are printed, never asserted: only that each figure is there and positive.
"""

from __future__ import annotations

import json
import subprocess

import pytest

from ftgspp.bench import compile_probe, main
from ftgspp.bench.render import format_render_table


def test_bench_render_prints_one_json_line(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["render", "--n", "200", "--width", "40", "--height", "30", "--repeats", "2", "--warmup", "1",
            "--no-compile-times", "--json"]  # fmt: skip
    assert main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    result = json.loads(lines[0])
    assert {"reference", "cpu"} <= set(result["backends"])
    for name, t in result["backends"].items():
        assert t["fwd_ms"] > 0 and t["fwd_bwd_ms"] > 0 and result["ratios"][name]["fwd_bwd"] > 0
    assert (result["n"], result["width"], result["height"]) == (200, 40, 30)
    assert set(result["numba_compile_s"]) == {"cold", "cached", "cold_raster_ms", "cached_raster_ms"}
    stages = result["stages"]  # the other stages of a cpu render, each against what it replaces
    assert set(stages["prepare"]) == {"autograd_ms", "fused_ms"}
    assert set(stages["ssim_loss"]) == {"conv2d_ms", "numba_ms"}
    assert all(t > 0 for stage in stages.values() for t in stage.values())


def test_bench_render_reports_the_compile_probe(monkeypatch: pytest.MonkeyPatch) -> None:
    """The probe's two subprocesses (cold, cached) each print first-call seconds and raster ms."""
    outputs = iter(["numba noise\n21.5 4.25\n", "0.5 4.0\n"])
    monkeypatch.setattr(compile_probe.subprocess, "run",
                        lambda argv, **kw: subprocess.CompletedProcess(argv, 0, stdout=next(outputs), stderr=""))
    probe = compile_probe.numba_compile_seconds()
    assert probe == {"cold": 21.5, "cached": 0.5, "cold_raster_ms": 4.25, "cached_raster_ms": 4.0}
    result = {"n": 10, "n_visible": 10, "width": 32, "height": 24, "repeats": 1, "ratios": {}, "yardstick": None,
              "backends": {"cpu": {"fwd_ms": 1.0, "fwd_bwd_ms": 2.0}}, "numba_compile_s": probe,
              "load_average": [0.0, 0.0], "cpu_count": 2}  # fmt: skip
    table = format_render_table(result)
    assert "cold 21.5 s, cached 0.50 s" in table and "4.25 ms" in table and "(1.06x)" in table
    failed = dict(probe, cached=None, cached_raster_ms=None)  # the cached probe failed: no line, no crash
    assert "numba compile" not in format_render_table(dict(result, numba_compile_s=failed))


def test_the_kernel_warm_up_runs_every_kernel_it_names() -> None:
    from ftgspp.bench.warmup import warm_up

    assert warm_up() >= 0.0  # it raised on the rasterizer's [N, 2] radii before (study run's warm-up failed)


PARTS_PROBE = """
from ftgspp.bench import warmup
kernels = warmup._dispatchers()
names = lambda: sorted(d.py_func.__module__.rsplit(".", 1)[-1] + "." + d.py_func.__qualname__
                       for d in kernels if d.signatures)
warmup.warm_up("fused")
print(names())
warmup.warm_up("rest")
print(names())
print(len(kernels))
"""


def test_the_warm_up_halves_together_call_every_kernel_and_the_fused_half_only_its_own() -> None:
    import sys

    from ftgspp.bench.warmup import warm_up

    out = subprocess.run([sys.executable, "-c", PARTS_PROBE], capture_output=True, text=True, timeout=600, check=True)
    fused, both, total = out.stdout.strip().splitlines()
    # in a fresh process, the fused half compiles the two methods' fused stages and nothing else
    assert eval(fused) == ["freetime_fused.prepare_backward", "freetime_fused.prepare_forward",
                           "stg_fused.prepare_backward", "stg_fused.prepare_forward"]
    assert len(eval(both)) == int(total)  # every kernel study run's warm-up promises
    with pytest.raises(ValueError, match="unknown warm-up part"):
        warm_up("half")


def test_the_parallel_warm_up_reports_a_failed_child(monkeypatch) -> None:
    from ftgspp.bench import warmup

    monkeypatch.setattr(warmup, "warm_up", lambda part=None: 0.0)
    real = subprocess.Popen
    monkeypatch.setattr(warmup.subprocess, "Popen",
                        lambda argv, **kw: real([argv[0], "-c", "import sys; sys.exit('no compiler here')"], **kw))
    with pytest.raises(RuntimeError, match="fused stages' warm-up failed: no compiler here"):
        warmup.warm_up_parallel(jobs=2)
    assert warmup.warm_up_parallel(jobs=1) == 0.0
