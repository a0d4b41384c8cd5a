"""How right the initial points are: SIFT, SIFT + fill and dense matching against the true depth.

For each scene of a stated list (generated on first use into ``--cache``), loaded as the quick
profile loads it (``data.downsample=2``), with the quick profile's initialisation (``InitConfig``'s
defaults, a budget of 5,000 points): real points per keyframe and the median and 90th percentile
of their relative depth error against the scene's ground truth (``ftgspp.init.quality``: ``|z - d|
/ d`` in the training camera where it is smallest) for

- ``sift``: the SIFT matcher's triangulated points;
- ``sift+fill``: the whole budget of ``points.initialize`` with SIFT (its points and their jittered
  copies);
- ``dense``: the dense matcher's points (``init.dense_check=off``), and ``dense+fill`` its budget;
- ``rule``: what ``init.dense_check`` (its default) chose for ``init.matcher=dense``, and what it
  decided on: the dense points' coverage of the views and the dense flow's median depth gap to SIFT.

``--check-unchanged`` also compares, per scene, the initial point arrays of ``init.matcher=dense``
with and without the rule (seed 0): identical, or how many points differ (all of them where the rule
fell back to SIFT). Nothing is asserted.

    .venv/bin/python benchmarks/init_accuracy.py                    # the development scenes
    .venv/bin/python benchmarks/init_accuracy.py --scenes presets --check-unchanged

The lists: ``dev``, the scenes the rule was designed and tuned on (docs/init.md); ``presets``, the
quick profile's own scenes (studio, fast_motion, transient, long_slow, short_fast). The held-out
validation scenes of studies/init_matcher.yaml are deliberately not here.
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BUDGET = 5_000  # conf/profile/quick.yaml
DOWNSAMPLE = 2  # conf/profile/quick.yaml

# name -> (writer, arguments): "spheres" is harness/run/spheres.py, anything else an ftgspp synth preset
SCENES: dict[str, dict[str, tuple[str, dict]]] = {
    "dev": {
        "sph_d0": ("spheres", dict(seed=0)),
        "sph_d1_missing_shift": ("spheres", dict(seed=1, missing=3, color_gain=0.02)),
        "sph_d2_textured": ("spheres", dict(seed=2, texture=0.5)),
        "sph_d3_192": ("spheres", dict(seed=0, width=192, height=144)),
        "sph_d4_narrow": ("spheres", dict(seed=3, spacing_deg=4.0)),
        "sph_d5_wide6": ("spheres", dict(seed=4, spacing_deg=14.0, n_cameras=6)),
        "sph_d6_tex192_shift": ("spheres", dict(seed=5, texture=0.5, width=192, height=144, color_gain=0.03)),
        "sph_d7_128": ("spheres", dict(seed=6, width=128, height=96)),
        "sph_d8_128tex_missing": ("spheres", dict(seed=7, width=128, height=96, texture=0.5, missing=2,
                                                  color_gain=0.02)),
        "sph_d9_busy": ("spheres", dict(seed=8, texture=0.8, n_moving=4, n_still=6, speed=1.5, noise=0.01,
                                        color_gain=0.02)),
        "sph_d10_busy128": ("spheres", dict(seed=9, texture=0.8, n_moving=4, n_still=6, speed=1.5, noise=0.01,
                                            width=128, height=96)),
        "plain": ("plain", dict(seed=0)),
        "studio_96": ("studio", dict(seed=0, width=96, height=72)),
        "studio_5cam": ("studio", dict(seed=0, n_cameras=5)),
        "fast_motion_128": ("fast_motion", dict(seed=0, width=128, height=96)),
    },
    "presets": {name: (name, dict(seed=0)) for name in ("studio", "fast_motion", "transient", "long_slow",
                                                         "short_fast")},
}


def ensure(cache: Path, name: str, writer: str, args: dict) -> Path:
    """The scene's folder, written on first use."""
    out = cache / name
    if (out / "poses_bounds.npy").is_file():
        return out
    print(f"generating {name} ...", flush=True)
    if writer == "spheres":
        from harness.run.spheres import generate

        generate(out, **args)
    else:
        from ftgspp.data.synthetic.build import generate

        generate(out, layout="dynerf", preset=writer, overwrite=True, **args)
    return out


def _errors(scene, frames: list[int], points: list[np.ndarray]) -> np.ndarray:
    from ftgspp.init.quality import relative_depth_errors

    errs = [relative_depth_errors(scene, f, p) for f, p in zip(frames, points)]
    return np.concatenate(errs) if errs else np.zeros(0)


def measure(path: Path, check_unchanged: bool) -> dict[str, dict]:
    """Per arm: real points per keyframe (median), depth error median / p90 (and the rule's choice)."""
    from ftgspp.config import DataConfig, InitConfig
    from ftgspp.data.load import load_scene
    from ftgspp.init.dense import dense_trusted, sift_depth_gaps, triangulate_keyframe_dense
    from ftgspp.init.points import depth_range, initialize, keyframes, sift_pair_matches, triangulate_keyframe

    scene = load_scene(DataConfig(path=str(path), downsample=DOWNSAMPLE))
    sift_cfg = InitConfig(matcher="sift")
    dense_cfg = InitConfig(matcher="dense", dense_check="off")
    rule_cfg = InitConfig(matcher="dense")
    near, far = depth_range(scene, sift_cfg)
    kfs = keyframes(scene, sift_cfg)
    row: dict[str, dict] = {}
    for arm, cfg in (("sift", sift_cfg), ("dense", dense_cfg)):
        if arm == "sift":
            pts = [triangulate_keyframe(scene, f, cfg, near, far)[0] for f in kfs]
        else:
            pts, gaps, coverages = [], [], []
            for f in kfs:
                flows: dict = {}
                P, _, counts = triangulate_keyframe_dense(scene, f, cfg, near, far, flows=flows, measure_coverage=True)
                pts.append(P)
                coverages.append(counts["coverage"])
                sift = [m[:4] for m in sift_pair_matches(scene, f, cfg, near, far, exclusive=False)[0]]
                gaps.append(sift_depth_gaps(scene, sift, flows))
            trusted, seen = dense_trusted(rule_cfg, coverages, gaps)
        e = _errors(scene, kfs, pts)
        row[arm] = dict(points=float(np.median([len(p) for p in pts])), errors=e)
        full = initialize(scene, cfg, BUDGET, seed=0)
        e = _errors(scene, kfs, [full.means[full.keyframe == k] for k in range(len(kfs))])
        row[arm + "+fill"] = dict(points=float(np.median([len(p) for p in pts])), errors=e, init=full)
    row["rule"] = dict(choice="dense" if trusted else "sift+fill", coverage=seen["coverage"],
                       disagreement=seen.get("disagreement", float("nan")))
    if check_unchanged:
        ruled = initialize(scene, rule_cfg, BUDGET, seed=0)
        before = row["dense+fill"]["init"]
        same = all(np.array_equal(getattr(ruled, f), getattr(before, f)) for f in ("means", "colors", "times",
                                                                                  "velocities", "spacing"))
        differ = int(np.any(ruled.means != before.means, axis=1).sum()) if len(ruled) == len(before) else len(ruled)
        row["rule"]["unchanged"] = "identical" if same else f"{differ} of {len(ruled)} points differ"
    row["size"] = dict(width=scene.cameras[scene.train_ids[0]].width, height=scene.cameras[scene.train_ids[0]].height)
    return row


def fmt(e: np.ndarray) -> str:
    if not len(e):
        return "– | –"
    return f"{100 * np.median(e):.1f} % | {100 * np.quantile(e, 0.9, method='inverted_cdf'):.1f} %"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="dev", choices=sorted(SCENES), help="which list of scenes")
    ap.add_argument("--only", nargs="*", default=None, help="these scenes of the list only")
    ap.add_argument("--cache", default="/tmp/ftgspp_init_accuracy", help="where the scenes are written")
    ap.add_argument("--check-unchanged", action="store_true", help="compare dense points with and without the rule")
    args = ap.parse_args(argv)
    logging.disable(logging.INFO)
    cache = Path(args.cache)
    print(f"| scene | trained at | arm | real points / keyframe | depth error median | p90 | dense coverage |"
          f" depth gap to SIFT | rule chose |{' points with the rule |' if args.check_unchanged else ''}")
    print(f"|---|---|---|---|---|---|---|---|---|{'---|' if args.check_unchanged else ''}")
    for name, (writer, sargs) in SCENES[args.scenes].items():
        if args.only and name not in args.only:
            continue
        r = measure(ensure(cache, name, writer, sargs), args.check_unchanged)
        size = f"{r['size']['width']}x{r['size']['height']}"
        chose = r["rule"]["choice"]
        extra = f" {r['rule']['unchanged']} |" if args.check_unchanged else ""
        for arm in ("sift", "sift+fill", "dense", "dense+fill"):
            print(f"| {name} | {size} | {arm} | {r[arm]['points']:.0f} | {fmt(r[arm]['errors'])} |"
                  f" {r['rule']['coverage']:.2f} | {r['rule']['disagreement']:.3f} | {chose} |{extra}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
