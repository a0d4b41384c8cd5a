"""What dense-matching initialisation costs a quick run, and what it makes (issue 45).

Trains one run per matcher (``init.matcher=sift`` and ``dense``; same seed, scene and profile)
with ``ftgspp train`` in a fresh output folder each, one after the other, and reports from each
run's ``metrics.json`` and ``init.json``: initialisation seconds (scene decoding, matching,
triangulation, velocities: the trainer's ``init_seconds``), training seconds, the real points per
keyframe and their share of the budget, the initial velocities' error on moving and static
points against the scene's ground truth, and held-out PSNR. The figure of interest is the extra
initialisation time of ``dense`` as a share of the ``sift`` run's init + training time (issue 45
allows about 10 %). One seed: PSNR is descriptive. Nothing is asserted.

    .venv/bin/python benchmarks/init_cost.py                       # studio, quick profile
    .venv/bin/python benchmarks/init_cost.py --velocity flow --combine rays --json out.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("init_points_per_keyframe_median", "init_real_share", "init_velocity_error_moving",
        "init_velocity_true_speed_moving", "init_velocity_error_static")


def train(scene: Path, out: Path, profile: str, overrides: list[str]) -> dict:
    """One ``ftgspp train`` run; its metrics and init statistics."""
    cmd = [sys.executable, "-m", "harness.cli.ftgspp_cmd", "train", f"profile={profile}", f"data.path={scene}",
           f"hydra.run.dir={out}", "eval_lpips=[]", "diagnostics=false", *overrides]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True)
    metrics = json.loads((out / "metrics.json").read_text())
    init = json.loads((out / "init.json").read_text()) if (out / "init.json").is_file() else {}
    return {**{k: metrics.get(k) for k in ("init_seconds", "train_seconds", "psnr")}, **init}


def compare(runs: dict[str, dict]) -> dict:
    """The dense run's extra initialisation time as a share of the sift run's init + training."""
    sift, dense = runs["sift"], runs["dense"]
    extra = dense["init_seconds"] - sift["init_seconds"]
    return {"extra_init_seconds": extra, "extra_share_of_a_run": extra / (sift["init_seconds"] + sift["train_seconds"])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="/tmp/ftgspp_bench/studio", help="synthetic scene (generated if absent)")
    ap.add_argument("--profile", default="quick")
    ap.add_argument("--velocity", default="knn", choices=["knn", "flow"])
    ap.add_argument("--combine", default="mean", choices=["mean", "lsq", "rays"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="write the numbers here")
    args = ap.parse_args(argv)
    scene = Path(args.scene)
    if not (scene / "gt").is_dir():
        from ftgspp.data.synthetic.build import generate

        print(f"generating studio into {scene} ...", flush=True)
        generate(scene, layout="dynerf", preset="studio", seed=0, overwrite=True)
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for matcher in ("sift", "dense"):
            over = [f"init.matcher={matcher}", f"init.velocity={args.velocity}", f"init.flow_combine={args.combine}",
                    f"seed={args.seed}"]
            runs[matcher] = train(scene, Path(tmp) / matcher, args.profile, over)
            r = runs[matcher]
            print(f"{matcher:5s}: init {r['init_seconds']:.2f} s, training {r['train_seconds']:.1f} s, PSNR"
                  f" {r['psnr']:.2f} dB; " + ", ".join(f"{k.removeprefix('init_')} {r[k]:.3g}" for k in KEYS if k in r),
                  flush=True)
    out = {"runs": runs, **compare(runs), "profile": args.profile, "velocity": args.velocity, "combine": args.combine}
    print(f"dense adds {out['extra_init_seconds']:.2f} s of initialisation: {100 * out['extra_share_of_a_run']:.1f} %"
          " of the sift run's init + training")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
