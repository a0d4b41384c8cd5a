"""benchmarks/init_cost.py: one run per matcher, the dense run's extra init time as a share of a run."""

from __future__ import annotations

import json

from tests.bench.bench_scripts import load_script


def test_init_cost_trains_both_matchers_and_reports_what_each_init_made(tiny_scene_dir, tmp_path, capsys):
    bench = load_script("init_cost")
    out = tmp_path / "cost.json"
    assert bench.main(["--scene", str(tiny_scene_dir), "--profile", "smoke", "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    sift, dense = got["runs"]["sift"], got["runs"]["dense"]
    assert dense["init_points_per_keyframe_median"] > 3 * sift["init_points_per_keyframe_median"]
    assert dense["init_matcher_dense"] == 1 and sift["init_matcher_dense"] == 0
    share = (dense["init_seconds"] - sift["init_seconds"]) / (sift["init_seconds"] + sift["train_seconds"])
    assert got["extra_share_of_a_run"] == share
    assert "dense adds" in capsys.readouterr().out
