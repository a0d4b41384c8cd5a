"""Command line of ``ftgspp bench``: parses ``render`` / ``train`` / ``scale`` and prints each
result as a table or, with ``--json``, as one JSON line.

    ftgspp bench render [--n 5000] [--width 128 --height 96] [--repeats 10] [--json]
    ftgspp bench train [--iterations 200] [--budget 5000] [--repeats 2] [--breakdown] [--after N] [--json]
    ftgspp bench scale [--counts 1000,5000,20000,100000] [--sizes 128x96,256x192,512x384] [--json]

``render`` and ``train`` take ``--target CPU`` (e.g. ``haswell``, ``znver1``, ``skylake-avx512``):
the same benchmark in a child process whose Numba kernels are compiled for that LLVM CPU
(``ftgspp.bench.isa``). Every result names the host's and the kernels' vector ISA.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ftgspp.bench.isa import CHILD_FLAG
from ftgspp.errors import InputError


def build_parser() -> argparse.ArgumentParser:
    """The ``ftgspp bench`` parser with its three subcommands."""
    parser = argparse.ArgumentParser(prog="ftgspp bench", description="Time rasterization and training.")
    sub = parser.add_subparsers(dest="command", required=True)
    render = sub.add_parser("render", help="forward / forward+backward of every rasterization backend")
    render.add_argument("--n", type=int, default=5000, help="number of 3D Gaussians")
    render.add_argument("--width", type=int, default=128)
    render.add_argument("--height", type=int, default=96)
    render.add_argument("--repeats", type=int, default=10, help="timed repeats per backend (median)")
    render.add_argument("--warmup", type=int, default=2)
    render.add_argument("--yardstick-repeats", type=int, default=1, help="0 skips the dense yardstick")
    render.add_argument("--no-compile-times", action="store_true", help="skip the Numba compile probe")
    render.add_argument("--seed", type=int, default=0)
    render.add_argument("--json", action="store_true", help="print one JSON line instead of a table")
    render.add_argument("--asm", action="store_true", help="count the vector registers in the raster kernels "
                        "and the instructions of their RGB pixel loops (ftgspp/bench/asm_census.py; "
                        "compiles them in a child process with an empty cache)")
    render.add_argument("--target", default="host", help="LLVM CPU to compile the kernels for (default: host)")
    train = sub.add_parser("train", help="whole training iterations of every backend (ftgspp/bench/train_speed.py)")
    train.add_argument("--iterations", type=int, default=200)
    train.add_argument("--budget", type=int, default=5000, help="number of Gaussians")
    train.add_argument("--repeats", type=int, default=2)
    train.add_argument("--width", type=int, default=128)
    train.add_argument("--height", type=int, default=96)
    train.add_argument("--backends", default="", help="comma-separated (default: every available one)")
    train.add_argument("--breakdown", action="store_true", help="also time every phase of an iteration")
    train.add_argument("--models", default="ftgs",
                       help="comma-separated methods (conf/model/<name>.yaml), each timed on each backend (default: ftgs)")
    train.add_argument("--after", type=int, default=0,
                       help="time the iterations after the first AFTER (trained once per row, untimed; default 0)")
    train.add_argument("--json", action="store_true", help="print one JSON line instead of a table")
    train.add_argument("--target", default="host", help="LLVM CPU to compile the kernels for (default: host)")
    scale = sub.add_parser("scale", help="cost of an iteration over Gaussian counts x resolutions")
    scale.add_argument("--counts", default="1000,5000,20000,100000")
    scale.add_argument("--sizes", default="128x96,256x192,512x384")
    scale.add_argument("--iterations", type=int, default=30)
    scale.add_argument("--backend", default="cpu")
    scale.add_argument("--plot", type=Path, default=Path("benchmarks/cost_curve.png"))
    scale.add_argument("--json", action="store_true", help="print one JSON line instead of a table")
    return parser


def subcommands() -> list[str]:
    """The names of ``ftgspp bench``'s subcommands, in the order the parser defines them."""
    parser = build_parser()
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))  # argparse has no public way
    return list(action.choices)


def _sizes(text: str) -> list[tuple[int, int]]:
    try:
        return [(int(w), int(h)) for w, h in (s.lower().split("x") for s in text.split(","))]
    except ValueError:
        raise InputError("--sizes", f"expected WxH[,WxH...], got {text!r}") from None


def _without_target(argv: list[str]) -> list[str]:
    """``argv`` minus ``--target X`` / ``--target=X`` and ``--json`` (the child adds its own)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--target":
            skip = True
        elif not a.startswith("--target=") and a != "--json":
            out.append(a)
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ftgspp bench``. Returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    in_child = os.environ.get(CHILD_FLAG) == "1"
    if not in_child and (getattr(args, "target", "host") != "host" or getattr(args, "asm", False)):
        from ftgspp.bench.isa import run_for_target

        result = run_for_target(_without_target(argv), args.target)
        if args.json:
            print(json.dumps(result))
        elif args.command == "render":
            from ftgspp.bench.render import format_render_table

            print(format_render_table(result))
        else:
            from ftgspp.bench.train_speed import format_train_table

            print(format_train_table(result))
        return 0
    if args.command == "render":
        from ftgspp.bench.render import bench_render, format_render_table

        result = bench_render(
            n=args.n, width=args.width, height=args.height, repeats=args.repeats, warmup=args.warmup,
            yardstick_repeats=args.yardstick_repeats, compile_times=not args.no_compile_times, seed=args.seed,
        )  # fmt: skip
        if args.asm:
            from ftgspp.bench.isa import kernel_registers

            result["registers"] = kernel_registers()
        print(json.dumps(result) if args.json else format_render_table(result))
        return 0
    if args.command == "train":
        from ftgspp.bench.train_speed import bench_train, format_train_table

        if args.after < 0:
            raise InputError("--after", f"must be 0 or more iterations, got {args.after}")
        result = bench_train(iterations=args.iterations, budget=args.budget, repeats=args.repeats,
                             width=args.width, height=args.height, breakdown=args.breakdown, after=args.after,
                             backends=[b for b in args.backends.split(",") if b] or None,
                             models=[m for m in args.models.split(",") if m] or None)
        print(json.dumps(result) if args.json else format_train_table(result))
        return 0
    from ftgspp.bench.scale import bench_scale, format_scale_table, plot_scale

    counts = [int(c) for c in args.counts.split(",")]
    result = bench_scale(counts, _sizes(args.sizes), args.iterations, args.backend,
                         echo=(lambda s: print(s, file=sys.stderr)) if args.json else print)
    result["plot"] = str(plot_scale(result, args.plot))
    print(json.dumps(result) if args.json else format_scale_table(result) + f"\nplot: {result['plot']}")
    return 0
