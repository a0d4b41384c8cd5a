"""`study check`: each run against a committed report gets one class (identical, evaluation
differs, expected to differ, differs unexpectedly, not compared), the verdict counts them, and
`--strict` fails only on a run that differs unexpectedly; a trained model's digest is its bits."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
import torch

from harness.analysis import reproduction as rep
from harness.analysis.aggregate import metric_columns

REF = "reports/toy/runs.csv"


def run(variant: str = "baseline", seed: int = 0, **kw: object) -> dict[str, object]:
    """One row of a per-run frame: a finished portable run with training, evaluation,
    diagnostics, timing and system numbers."""
    row: dict[str, object] = dict(
        variant=variant, scene="studio", seed=seed, config_hash=f"c{variant}{seed}", status="FINISHED",
        trainer_fingerprint="f22b054564b5", domain="c8ad70a178", determinism="portable", cpu_capability="DEFAULT",
        cpu_model="Intel(R) Xeon(R) Processor", torch_threads="1",
        train_psnr=31.13, l1=0.0311, n_gaussians=5000.0, relocated_total=996.0, loss=0.0214,
        psnr=29.31, lpips_alex=0.0570, lifetime_median_fraction=0.139, eval_frames=30.0,
        train_seconds=34.6, peak_rss_mb=806.8, **{"system/cpu_utilization_percentage": 100.0})
    row.update(kw)
    return row


def classify(ours: list[dict], reference: list[dict]) -> pd.DataFrame:
    return rep.compare(pd.DataFrame(ours), pd.DataFrame(reference))


def test_the_registry_sorts_metrics_into_training_and_evaluation_sides() -> None:
    assert [rep.side(m) for m in ("train_psnr", "l1", "n_gaussians", "relocated_total")] == ["training"] * 4
    assert [rep.side(m) for m in ("psnr", "lpips_alex", "lifetime_median_fraction")] == ["evaluation"] * 3
    # timings, the thread-dependent loss, system samples and derived differences are not compared
    assert [rep.side(m) for m in ("train_seconds", "loss", "system/cpu_utilization_percentage", "gap_ssim")] == [""] * 4


def test_the_inits_measurements_are_compared_with_the_evaluation_and_its_decisions_with_the_training() -> None:
    """The demo's case on another CPU model (znver4 against znver5, 2026-11-29): models bit for bit
    equal, the init's float64 measurements 6.5e-16 apart; what the init decided is training."""
    measured = ("init_dense_sift_disagreement", "init_depth_error_median", "init_depth_error_p90",
                "init_dense_coverage", "init_velocity_error_moving", "init_velocity_error_static")
    assert [rep.side(m) for m in measured] == ["evaluation"] * len(measured)
    assert [rep.side(m) for m in ("init_dense_fallback", "init_points_total", "init_matcher_dense")] == ["training"] * 3
    ref = [run(model_digest="ab" * 32, init_dense_sift_disagreement=0.0246, init_dense_fallback=0.0)]
    here = [run(model_digest="ab" * 32, init_dense_sift_disagreement=0.0246 + 6.5e-16, init_dense_fallback=0.0)]
    assert classify(here, ref)["class"].tolist() == ["evaluation differs"]
    flipped = [run(model_digest="ab" * 32, init_dense_sift_disagreement=0.0246, init_dense_fallback=1.0)]
    assert classify(flipped, ref)["class"].tolist() == ["differs unexpectedly"]


def test_identical_runs_with_equal_model_bits_ignore_timings() -> None:
    ours = [run(model_digest="ab" * 32, train_seconds=50.0, loss=0.0215, peak_rss_mb=900.0)]
    frame = classify(ours, [run(model_digest="ab" * 32)])
    row = frame.iloc[0]
    assert (row["class"], row.model_bits, row.why) == ("identical", "equal", "")
    assert row.training_compared == 4 and row.evaluation_compared == 4  # train_psnr, l1, ...; psnr, lpips, ...
    assert rep.summary(frame, REF)[:2] == [
        f"1 run compared with the committed report ({REF}): 1 training identical (bit for bit), of which 1 in every"
        " metric and 0 differ only in evaluation; 0 expected to differ; 0 differ unexpectedly",
        "  training identical: model bits equal (1 run)"]
    assert not rep.strict_failure(frame)


def test_training_identical_runs_that_differ_only_in_evaluation_name_the_metrics_and_how_much() -> None:
    """The committed secret5 case: portable runs trained bit for bit alike, LPIPS and a lifetime
    diagnostic moved with the evaluation code; the reference has no model digest yet."""
    ref = [run(seed=s) for s in range(3)]
    here = [run(seed=0, trainer_fingerprint="9a69c0ffee00", lpips_alex=0.0570 + 2e-10, model_digest="ab" * 32),
            run(seed=1, trainer_fingerprint="9a69c0ffee00", lpips_alex=0.0570 - 1e-10,
                lifetime_median_fraction=0.139 + 1.2e-7, model_digest="cd" * 32),
            run(seed=2, trainer_fingerprint="9a69c0ffee00", model_digest="ef" * 32)]
    frame = classify(here, ref)
    assert frame["class"].tolist() == ["evaluation differs", "evaluation differs", "identical"]
    assert set(frame.model_bits) == {"not recorded in the reference"}
    assert frame.evaluation_differing[1] == "lifetime_median_fraction 1.2e-07, lpips_alex 1e-10"
    assert frame.training_differing.tolist() == ["", "", ""] and frame.psnr_diff.tolist() == [0.0, 0.0, 0.0]
    lines = rep.summary(frame, REF)
    assert lines[0] == (f"3 runs compared with the committed report ({REF}): 3 training identical (bit for bit), of"
                        " which 1 in every metric and 2 differ only in evaluation (lifetime_median_fraction by ≤"
                        " 1.2e-07, lpips_alex by ≤ 2e-10); 0 expected to differ; 0 differ unexpectedly")
    assert "  training identical: model bits not recorded in the reference (3 runs)" in lines
    assert "  2 differ only in evaluation: trainer code (f22b054564b5 in the reference, 9a69c0ffee00 here)" in lines
    assert not rep.strict_failure(frame)


def test_a_non_portable_run_of_another_cpu_is_expected_to_differ() -> None:
    dispatch = dict(determinism="default", cpu_capability="AVX2")
    ref = [run("dispatch_avx2", s, domain="f9cf341d61", **dispatch) for s in range(2)]
    here = [run("dispatch_avx2", s, domain="77e0aa01b2", cpu_model="AMD EPYC 9R14", train_psnr=31.2,
                psnr=29.31 - 0.13 * s, **dispatch) for s in range(2)]
    frame = classify(here, ref)
    assert frame["class"].tolist() == ["expected to differ"] * 2
    assert set(frame.reason) == {"another determinism domain"}
    assert frame.why[0] == ("another determinism domain (f9cf341d61 in the reference, 77e0aa01b2 here: non-portable"
                            " (default mode), CPU Intel(R) Xeon(R) Processor in the reference, AMD EPYC 9R14 here)")
    assert frame.training_differing[0] == "train_psnr 0.07"
    lines = rep.summary(frame, REF)
    assert lines[0].endswith("0 training identical (bit for bit); 2 expected to differ (another determinism domain);"
                             " 0 differ unexpectedly")
    assert lines[1] == f"  2 expected to differ: {frame.why[0]}; PSNR by up to 0.1300 dB"
    assert not rep.strict_failure(frame)


def test_portable_runs_of_other_package_versions_or_configs_are_other_runs() -> None:
    ref = [run(seed=0), run(seed=1)]
    here = [run(seed=0, domain="0badc0de00", l1=0.04), run(seed=1, config_hash="c-smoke", l1=0.04)]
    frame = classify(here, ref)
    assert frame["class"].tolist() == ["expected to differ"] * 2
    assert frame.reason.tolist() == ["another determinism domain", "another config"]
    assert "package versions or another setting" in frame.why[0]  # a portable domain does not depend on the CPU
    assert rep.summary(frame, REF)[0].endswith(
        "2 expected to differ (1 another determinism domain, 1 another config); 0 differ unexpectedly")


def test_training_that_differs_in_the_same_domain_differs_unexpectedly() -> None:
    ref = [run(seed=s) for s in range(3)]
    here = [run(seed=0, n_gaussians=4999.0, trainer_fingerprint="9a69c0ffee00"),  # stale reference
            run(seed=1, relocated_total=995.0),  # same code, config and domain: unexplained
            run(seed=2, model_digest="ab" * 32)]
    ref[2]["model_digest"] = "cd" * 32  # every number equal, the model bits not
    frame = classify(here, ref)
    assert frame["class"].tolist() == ["differs unexpectedly"] * 3
    assert frame.reason.tolist() == ["trainer code", "unexplained", "unexplained"]
    assert frame.training_differing.tolist() == ["n_gaussians 1", "relocated_total 1", "model bits"]
    assert frame.model_bits[2] == "differ"
    lines = rep.summary(frame, REF)
    assert lines[0].endswith("0 expected to differ; 3 differ unexpectedly (2 unexplained, 1 trainer code)")
    assert "  2 differ unexpectedly: unexplained: same config, code and determinism domain; PSNR by up to 0.0000 dB" \
        in lines
    assert rep.strict_failure(frame)


def test_nan_metrics_count_only_when_one_side_recorded_them() -> None:
    ref = [run(seed=0, cc_mean_delta=math.nan), run(seed=1, lpips_alex=0.05)]
    here = [run(seed=0, cc_mean_delta=math.nan), run(seed=1, lpips_alex=math.nan)]  # LPIPS weights missing here
    frame = classify(here, ref)
    assert frame["class"].tolist() == ["identical", "evaluation differs"]
    assert frame.evaluation_differing[1] == "lpips_alex (only in the reference)"
    assert math.isinf(frame["diff.lpips_alex"][1])
    assert "(lpips_alex recorded on one side only)" in rep.summary(frame, REF)[0]


def test_runs_missing_or_unfinished_on_either_side_are_not_compared() -> None:
    untrained = dict(train_psnr=math.nan, l1=math.nan, n_gaussians=math.nan, relocated_total=math.nan)
    ref = [run(seed=0), run(seed=1), run(seed=2, status="FAILED"), run(seed=4, **untrained)]
    here = [run(seed=0), run(seed=1, status="FAILED"), run(seed=2), run(seed=3), run(seed=4, **untrained)]
    frame = classify(here, ref)
    assert frame["class"].tolist() == ["identical"] + ["not compared"] * 4
    assert frame.why.tolist()[1:] == ["not finished here", "not finished in the reference", "not in the reference",
                                      "no training metric or model digest recorded on both sides"]
    lines = rep.summary(frame, REF)
    assert lines[0].startswith(f"1 run compared with the committed report ({REF}): 1 training identical")
    assert lines[-1].startswith("4 not compared: ")
    assert not rep.strict_failure(frame)
    assert rep.strict_failure(classify([run(seed=1, status="FAILED")], [run(seed=1)]))  # nothing compared


def test_the_reference_is_read_with_its_ids_as_text_and_its_floats_exact(tmp_path: Path) -> None:
    row = run(domain="1234567890", config_hash="12e4567890", psnr=29.308904886822308, lpips_alex=0.1 + 0.2)
    pd.DataFrame([row]).to_csv(tmp_path / "runs.csv", index=False)
    ref = rep.read_reference(str(tmp_path / "runs.csv"))
    assert (ref.domain[0], ref.config_hash[0]) == ("1234567890", "12e4567890")
    assert rep.compare(pd.DataFrame([row]), ref)["class"].tolist() == ["identical"]
    assert "model_digest" not in metric_columns(pd.DataFrame([run(model_digest="ab" * 32)]))


@pytest.mark.parametrize(("here", "code"), [
    ([run(seed=0, lpips_alex=0.06), run("dispatch_avx2", 0, domain="77e0aa01b2", determinism="default", l1=0.5)], 0),
    ([run(seed=0, l1=0.5), run("dispatch_avx2", 0)], 1),
])
def test_strict_check_fails_only_on_a_run_that_differs_unexpectedly(
        here: list[dict], code: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    import harness.report.results
    from harness.cli.study import main

    monkeypatch.chdir(tmp_path)
    pd.DataFrame([run(seed=0), run("dispatch_avx2", 0, domain="f9cf341d61", determinism="default")]).to_csv(
        tmp_path / "runs.csv", index=False)
    monkeypatch.setattr(harness.report.results, "collect", lambda name, sel: SimpleNamespace(df=pd.DataFrame(here)))
    assert main(["check", "toy", "--reference", str(tmp_path / "runs.csv")]) == 0
    assert main(["check", "toy", "--reference", str(tmp_path / "runs.csv"), "--strict"]) == code
    out = capsys.readouterr().out
    assert f"; {code} differ{'s' if code == 1 else ''} unexpectedly" in out
    written = pd.read_csv(tmp_path / "outputs/reports/toy/reproduction.csv")
    assert written["class"].tolist() == (["evaluation differs", "expected to differ"] if code == 0
                                         else ["differs unexpectedly", "identical"])


class Tags:
    """A tracker that keeps the tags it is given."""

    def __init__(self) -> None:
        self.tags: dict[str, str] = {}

    def log_params(self, params: dict) -> None:
        pass

    def log_metrics(self, metrics: dict, step: int | None = None) -> None:
        pass

    def log_artifact(self, path: object, artifact_path: str | None = None) -> None:
        pass

    def set_tags(self, tags: dict[str, str]) -> None:
        self.tags.update(tags)


def test_the_model_digest_is_the_same_for_the_same_config_and_seed_and_moves_with_one_bit(
        tiny_scene_dir: Path, tmp_path: Path) -> None:
    from ftgspp.config import TrainConfig
    from harness.run.training import model_digest, run_training

    def train(out: Path) -> str:
        cfg = TrainConfig()
        cfg.data.path, cfg.iterations, cfg.budget, cfg.backend, cfg.seed = str(tiny_scene_dir), 6, 200, "cpu", 3
        cfg.progress, cfg.diagnostics, cfg.init.keyframe_stride = False, False, 3
        tracker = Tags()
        assert run_training(cfg, out, tracker).status == "FINISHED"
        return tracker.tags["model_digest"]

    a, b = train(tmp_path / "a"), train(tmp_path / "b")
    assert a == b == model_digest(tmp_path / "a") and len(a) == 64
    params = torch.load(tmp_path / "b" / "gaussians.pt", weights_only=True)
    name = sorted(params)[-1]
    flat = params[name].reshape(-1).view(torch.int32)
    flat[0] ^= 1  # the last bit of one float
    torch.save(params, tmp_path / "b" / "gaussians.pt")
    assert model_digest(tmp_path / "b") != a
    assert model_digest(tmp_path / "empty") == ""
