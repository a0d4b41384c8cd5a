"""Why an STGS iteration costs more than a FreeTimeGS one at the same budget: a test of one cause.

``ftgspp bench train --models ftgs,stg --breakdown`` shows the gap is the rasterizer's, and its work
table shows why: STGS's Gaussians are drawn about as often per view as FreeTimeGS's but cover more
(tile, Gaussian) pairs, i.e. they are larger on screen. The two methods start them at different
sizes: FreeTimeGS at ``init.scale_factor`` (0.1) x the per-keyframe kNN spacing, STGS at a spacing
itself. This script times the pair three times, STGS started (overrides in this process only)

1. at the per-keyframe mean spacing (``model.init_spacing=keyframe``: its runs' start before issue 59);
2. at its public code's spacing, the root mean square distance to the 3 nearest among every
   keyframe's points (``model.init_spacing=union``, as configured; ftgspp/init/spacing.py);
3. at FreeTimeGS's size (the per-keyframe spacing x ``scale_factor``).

If the ratio falls to about 1 in the third, the gap is the work the initial size gives, not the code.

    .venv/bin/python benchmarks/stgs_gap.py [--iterations 100] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

from ftgspp.bench import train_speed
from ftgspp.bench.train_speed import bench_train, format_train_table
from ftgspp.config import InitConfig
from ftgspp.methods.stg import SpacetimeGaussians


def run(iterations: int, repeats: int) -> dict:
    named = train_speed.model_config
    from_points = SpacetimeGaussians.from_points.__func__
    factor = InitConfig().scale_factor

    def smaller(cls, means, colors, times, velocities, spacing, cfg, init, device="cpu"):
        return from_points(cls, means, colors, times, velocities, factor * spacing, cfg, init, device)

    def timed(rule: str) -> dict:
        train_speed.model_config = lambda name: replace(named(name), init_spacing=rule) if name == "stg" else named(name)
        try:
            return bench_train(iterations=iterations, repeats=repeats, backends=["cpu"], models=["ftgs", "stg"],
                               breakdown=True)
        finally:
            train_speed.model_config = named

    out = {"stgs_per_keyframe_spacing": timed("keyframe"), "stgs_union_spacing": timed("union")}
    SpacetimeGaussians.from_points = classmethod(smaller)
    try:
        out[f"stgs_per_keyframe_spacing_x{factor}"] = timed("keyframe")
    finally:
        SpacetimeGaussians.from_points = classmethod(from_points)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    result = run(args.iterations, args.repeats)
    if args.json:
        json.dump(result, sys.stdout, indent=1)
    else:
        for name, r in result.items():
            print(f"== {name}\n{format_train_table(r)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
