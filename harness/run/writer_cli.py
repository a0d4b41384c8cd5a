"""The command line of the harness's own scene writers (``python -m harness.run.known_size``,
``python -m harness.run.spheres``): ``--out DIR [--seed N] [--set KEY=JSON ...]``, exit status 2
with one line on bad input. A study run's ``command`` column gives it for such a scene
(``harness.spec.runs.standalone_command``)."""

from __future__ import annotations

import json
import sys
from typing import Any, Callable

from ftgspp.errors import InputError


def main(prog: str, description: str, generate: Callable[..., Any], example: str, argv: list[str] | None = None
         ) -> int:
    """Parse ``argv`` and call ``generate(out, seed=..., **arguments)``."""
    import argparse

    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", action="append", default=[], metavar="KEY=JSON", help=f"a scene argument, e.g. {example}")
    args = p.parse_args(argv)
    try:
        extra = {k: json.loads(v) for k, _, v in (item.partition("=") for item in args.set)}
        generate(args.out, seed=args.seed, **extra)
    except (InputError, json.JSONDecodeError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0
