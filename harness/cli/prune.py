"""``ftgspp prune RUN --keep F [--recover N] [--out DIR] [--data DIR] [--backend NAME]``.

Keeps the fraction F of a finished run's Gaussians with the highest spatio-temporal
significance, fine-tunes them for N iterations (default 10 % of the run's) and evaluates the
held-out views (``ftgspp/pruning.py``). Prints one summary line; the results are in
``OUT/prune.json`` and ``OUT`` is itself a loadable run. Bad input: one line, exit status 2.
"""

from __future__ import annotations

import argparse
import sys

from ftgspp.errors import InputError, exit_on_input_error
from ftgspp.pruning import prune_run, summary_line


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"error: {self.prog}: {message} (see ftgspp prune --help)", file=sys.stderr)
        raise SystemExit(2)


def _number(text: str, option: str, kind: type) -> float | int:
    try:
        return kind(text)
    except ValueError:
        raise InputError(option, f"not a number: {text!r}") from None


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, prune, print the summary line; ``InputError`` for bad input."""
    ap = _Parser(prog="ftgspp prune", description=__doc__.split("\n\n")[1].replace("\n", " "))
    ap.add_argument("run_dir", help="a finished training run (config.json + gaussians.pt)")
    ap.add_argument("--keep", required=True, help="fraction of the Gaussians to keep, in (0, 1]")
    ap.add_argument("--recover", default=None, help="recovery fine-tune iterations (default: 10%% of the run's)")
    ap.add_argument("--out", default=None, help="output folder (default RUN/pruned/keep<F>_recover<N>)")
    ap.add_argument("--data", default=None, help="scene folder (default: data.path of the run's config)")
    ap.add_argument("--backend", default=None, help="render backend (default: the run's)")
    args = ap.parse_args(argv)
    keep = float(_number(args.keep, "--keep", float))
    recover = None if args.recover is None else int(_number(args.recover, "--recover", int))
    results = prune_run(args.run_dir, keep, recover, out_dir=args.out, data=args.data, backend=args.backend)
    print(summary_line(results))
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except InputError as err:
        exit_on_input_error(err)
