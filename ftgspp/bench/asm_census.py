"""What the rasterizer's pixel loops execute per pixel, read from their machine code.

``ftgspp bench render --asm`` compiles the raster kernels in a child process (an empty cache:
Numba keeps no assembly of cached code) and passes their assembly here. ``pixel_loop`` finds the
compositing loop of the RGB path: among the innermost loops that evaluate ``exp_clamped`` (a
vector floor, ``vroundps`` / ``vrndscaleps``, then the float-to-int32 conversion ``vcvttps2dq``
that builds its 2^n; the output loop converts the stop slots, but floors nothing), one of the widest
vectors (not a remainder loop's narrower or unrolled scalar code) that stores the most tile-state
rows (the RGB path stores seven a pixel, the other path five). ``census`` sorts that loop's
instructions:

- ``alu``: vector instructions that compute (arithmetic, compares, blends, masked register moves,
  conversions, packs, extracts to registers, transfers between vector and general registers), the
  work of the vector units; ``alu_zmm`` of them on 512-bit registers;
- ``load`` / ``store``: vector moves, broadcasts, masked moves, gathers and scatters from / to
  memory, and extracts to memory (a load folded into an arithmetic instruction counts as ``alu``);
- ``move``: unmasked moves from a vector register to another (renamed away on recent x86 cores);
- ``mask``: AVX-512 mask-register instructions (``k...``);
- ``scalar``: the rest (addresses, loop counters, branches).

``lanes`` is the float32 lanes of the loop's widest vector register (16 in a ``zmm``, 8 in a
``ymm``), and ``pixels`` the pixels one pass through the loop composites: ``lanes`` times the
floors in the pass (one exp per vector of pixels; more when LLVM unrolled the loop).

A model, not measured here: if a 512-bit instruction holds a 256-bit unit for two cycles (as is
reported of AMD Zen 4), ``alu`` a pixel, ``alu_zmm`` counted twice, predicts the AVX2 / AVX-512
speed ratio of a loop bound by arithmetic (docs/benchmarks-history.md, 2026-11-30: the forward
pixel loop's measured ratio fits it, the backward's does not).
"""

from __future__ import annotations

import re

EXP_MARK = "vcvttps2dq"  # exp_clamped's 2^n, in every loop that evaluates a Gaussian on pixels
FLOOR = ("vroundps", "vrndscaleps")  # exp_clamped's n = floor(x log2 e + 1/2): one per exp
_LABEL = re.compile(r"^(\.LBB\d+_\d+):")
_JUMP = re.compile(r"^\s+j\w+\s+(\.LBB\d+_\d+)\s*$")
_OPERANDS = re.compile(r",\s*(?![^()]*\))")  # commas outside parentheses
KINDS = ("alu", "load", "store", "move", "mask", "scalar")
# opcodes that move data between memory and vector registers when an operand is in memory
_MEMORY_MOVES = ("vmov", "vbroadcast", "vpbroadcast", "vmaskmov", "vpmaskmov", "vgather", "vpgather",
                 "vscatter", "vpscatter", "vpextr", "vextract")  # fmt: skip
_REGISTER_MOVES = ("vmovaps", "vmovups", "vmovapd", "vmovupd", "vmovdqa", "vmovdqa32", "vmovdqa64", "vmovdqu",
                   "vmovdqu8", "vmovdqu16", "vmovdqu32", "vmovdqu64")  # fmt: skip
_VECTOR = re.compile(r"%[xyz]mm\d+")


def instructions(lines: list[str]) -> list[str]:
    """The instruction lines among assembly lines (no labels, directives or comments), stripped."""
    out = []
    for line in lines:
        text = line.split("#", 1)[0].strip()
        if text and not text.startswith(".") and not text.endswith(":"):
            out.append(text)
    return out


def kind(instruction: str) -> str:
    """Which of ``KINDS`` an AT&T-syntax x86-64 instruction (sources first, destination last) is."""
    op, *rest = instruction.split(None, 1)
    args = rest[0] if rest else ""
    if op.startswith("k"):
        return "mask"
    if not _VECTOR.search(args):
        return "scalar"
    operands = _OPERANDS.split(args)
    if op.startswith(_MEMORY_MOVES):
        if "(" in operands[-1]:
            return "store"
        if not op.startswith(("vpextr", "vextract")) and any("(" in o for o in operands[:-1]):
            return "load"
    if op in _REGISTER_MOVES and "{" not in args and all(_VECTOR.fullmatch(o.strip()) for o in operands):
        return "move"
    return "alu"


def innermost_loops(asm: str) -> list[list[str]]:
    """The instruction lines of each innermost loop of one module's assembly (LLVM numbers its
    labels per module): from a label to the first jump back to it, holding no other such loop."""
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
    """``KINDS`` counts of a loop body, ``alu_zmm``, its ``instructions``, ``lanes`` and
    ``pixels`` a pass (see the module docstring)."""
    counts = dict.fromkeys(KINDS, 0)
    alu_zmm = 0
    for ins in body:
        k = kind(ins)
        counts[k] += 1
        alu_zmm += k == "alu" and "%zmm" in ins
    text = " ".join(body)
    lanes = 16 if "%zmm" in text else 8 if "%ymm" in text else 4
    exps = sum(ins.startswith(FLOOR) for ins in body)
    return {**counts, "alu_zmm": alu_zmm, "instructions": len(body), "lanes": lanes, "pixels": lanes * max(exps, 1)}


def _evaluates_exp(body: list[str]) -> bool:
    return any(i.startswith(FLOOR) for i in body) and any(i.startswith(EXP_MARK) for i in body)


def pixel_loop(*modules: str) -> dict[str, int] | None:
    """``census`` of the RGB compositing loop in the assembly of one or more modules (a kernel's
    signatures; see the module docstring; of equal candidates, the shortest); None when no
    innermost loop evaluates exp."""
    loops = [body for asm in modules for body in innermost_loops(asm) if _evaluates_exp(body)]
    if not loops:
        return None
    return max((census(body) for body in loops),
               key=lambda c: (c["lanes"], c["store"] / c["pixels"], c["alu"], -c["instructions"]))
