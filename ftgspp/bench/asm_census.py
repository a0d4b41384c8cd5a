"""What the rasterizer's pixel loops execute per pixel, read from their machine code.

``ftgspp bench render --asm`` compiles the raster kernels in a child process (an empty cache:
Numba keeps no assembly of cached code) and passes their assembly here. ``pixel_loop`` finds the
compositing loop of the RGB path: among the innermost loops that evaluate ``exp_clamped`` (its
2^n is the only float-to-int32 conversion, ``vcvttps2dq``, of a pixel loop), one of the widest
vectors (not a remainder loop's narrower or unrolled scalar code) that stores the most tile-state
rows (the RGB path stores three colour rows more than the other). ``census`` sorts that loop's
instructions:

- ``alu``: vector instructions that compute (arithmetic, compares, blends, masked moves,
  conversions, packs and extracts), the work the vector units do;
- ``load`` / ``store``: vector moves and broadcasts from / to memory (a load folded into an
  arithmetic instruction counts as ``alu``);
- ``move``: register-to-register vector moves (renamed away on recent x86 cores);
- ``mask``: AVX-512 mask-register instructions (``k...``);
- ``scalar``: the rest (addresses, loop counters, branches).

``lanes`` is the float32 lanes of the loop's widest vector register (16 in a ``zmm``, 8 in a
``ymm``). One pass through the raster kernels' pixel loops composites one vector of pixels: no
unrolling, as read in their assembly for both targets (2026-11-30). On AMD Zen 4 a 512-bit
instruction holds a 256-bit unit for two cycles, so ``alu`` a pixel, ``zmm`` instructions counted
twice, gives the AVX2 / AVX-512 speed ratio of an arithmetic-bound loop: the forward loop's
measured ratio fits it, the backward's does not (docs/benchmarks-history.md, 2026-11-30).
"""

from __future__ import annotations

import re

EXP_MARK = "vcvttps2dq"  # exp_clamped's 2^n, in every loop that evaluates a Gaussian on pixels
_LABEL = re.compile(r"^(\.LBB\d+_\d+):")
_JUMP = re.compile(r"^\s+j\w+\s+(\.LBB\d+_\d+)\s*$")
_OPERANDS = re.compile(r",\s*(?![^()]*\))")  # commas outside parentheses
KINDS = ("alu", "load", "store", "move", "mask", "scalar")


def instructions(lines: list[str]) -> list[str]:
    """The instruction lines among assembly lines (no labels, directives or comments), stripped."""
    out = []
    for line in lines:
        text = line.split("#", 1)[0].strip()
        if text and not text.startswith(".") and not text.endswith(":"):
            out.append(text)
    return out


def kind(instruction: str) -> str:
    """Which of ``KINDS`` an AT&T-syntax x86-64 instruction is."""
    op, *rest = instruction.split(None, 1)
    args = rest[0] if rest else ""
    if op.startswith("k"):
        return "mask"
    if "mm" not in args:
        return "scalar"
    if op.startswith(("vmov", "vbroadcast")) and "{" not in args:  # a masked move selects: alu
        operands = _OPERANDS.split(args)
        if "(" in operands[-1]:
            return "store"
        return "load" if "(" in operands[0] else "move"
    return "alu"


def innermost_loops(asm: str) -> list[list[str]]:
    """The instruction lines of each innermost loop: from a label to the first jump back to it,
    holding no other such loop."""
    lines = asm.splitlines()
    where: dict[str, int] = {}
    spans: dict[str, tuple[int, int]] = {}
    for i, line in enumerate(lines):
        label = _LABEL.match(line)
        if label:
            where[label.group(1)] = i
        jump = _JUMP.match(line)
        if jump and jump.group(1) in where and jump.group(1) not in spans:
            spans[jump.group(1)] = (where[jump.group(1)], i)
    inner = [
        (s, e) for s, e in spans.values()
        if not any((s2, e2) != (s, e) and s <= s2 and e2 <= e for s2, e2 in spans.values())
    ]  # fmt: skip
    return [instructions(lines[s : e + 1]) for s, e in sorted(inner)]


def census(body: list[str]) -> dict[str, int]:
    """``KINDS`` counts of a loop body, its ``instructions`` and ``lanes`` (float32 per vector of
    its widest register)."""
    counts = dict.fromkeys(KINDS, 0)
    for ins in body:
        counts[kind(ins)] += 1
    text = " ".join(body)
    lanes = 16 if "%zmm" in text else 8 if "%ymm" in text else 4
    return {**counts, "instructions": len(body), "lanes": lanes}


def pixel_loop(asm: str) -> dict[str, int] | None:
    """``census`` of the RGB compositing loop of a raster kernel's assembly (see the module
    docstring); None when no innermost loop evaluates exp."""
    loops = [body for body in innermost_loops(asm) if any(ins.startswith(EXP_MARK) for ins in body)]
    if not loops:
        return None
    return max((census(body) for body in loops), key=lambda c: (c["lanes"], c["store"], c["alu"]))
