"""Why an STGS iteration costs more than a FreeTimeGS one at the same budget: a test of one cause.

``ftgspp bench train --models ftgs,stg --breakdown`` shows the gap is the rasterizer's, and its work
table shows why: STGS's Gaussians are drawn about as often per view as FreeTimeGS's but cover ~4x
the (tile, Gaussian) pairs, i.e. they are larger on screen. The two methods start them at different
sizes: FreeTimeGS at ``init.scale_factor`` (0.1) x the kNN spacing, STGS (as its public lite code)
at the spacing itself. This script times both again with STGS started at FreeTimeGS's size (its
``from_points`` given ``scale_factor`` x the spacing, for this process only: the method's rule is
unchanged). If the ratio falls to about 1, the gap is the work its initial size gives, not the code.

    .venv/bin/python benchmarks/stgs_gap.py [--iterations 100] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys

from ftgspp.bench.train_speed import bench_train, format_train_table
from ftgspp.config import InitConfig
from ftgspp.methods.stg import SpacetimeGaussians


def run(iterations: int, repeats: int) -> dict:
    as_published = bench_train(iterations=iterations, repeats=repeats, backends=["cpu"], models=["ftgs", "stg"],
                               breakdown=True)
    original = SpacetimeGaussians.from_points.__func__
    factor = InitConfig().scale_factor

    def smaller(cls, means, colors, times, velocities, spacing, cfg, init, device="cpu"):
        return original(cls, means, colors, times, velocities, factor * spacing, cfg, init, device)

    SpacetimeGaussians.from_points = classmethod(smaller)
    try:
        same_size = bench_train(iterations=iterations, repeats=repeats, backends=["cpu"], models=["ftgs", "stg"],
                                breakdown=True)
    finally:
        SpacetimeGaussians.from_points = classmethod(original)
    return {"stgs_initial_scale_as_published": as_published, f"stgs_initial_scale_x{factor}": same_size}


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
