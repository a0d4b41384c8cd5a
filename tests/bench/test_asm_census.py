"""The pixel-loop census of ``ftgspp bench render --asm`` (ftgspp/bench/asm_census.py).

Oracles: instruction kinds written out by hand from the x86 AT&T syntax; a loop nest whose
innermost loop is known; and a kernel compiled here whose stores and vector width are known
from its source and the compile target."""

from __future__ import annotations

import numpy as np

from ftgspp.bench.asm_census import census, innermost_loops, kind, pixel_loop
from ftgspp.bench.render import pixel_loop_line

# (instruction, kind), tab-separated as LLVM prints them
KINDS = [
    ("vmulps\t%zmm15, %zmm5, %zmm17", "alu"),
    ("vmulps\t(%r15){1to16}, %zmm16, %zmm17", "alu"),  # a folded broadcast load computes
    ("vmulps\t%zmm16, %zmm10, %zmm14 {%k3} {z}", "alu"),
    ("vcmpleps\t%zmm27, %zmm15, %k2 {%k2}", "alu"),
    ("vmovaps\t%zmm15, %zmm17 {%k3}", "alu"),  # a masked move selects
    ("vblendvps\t%ymm14, %ymm2, %ymm1, %ymm1", "alu"),
    ("vcvttps2dq\t%ymm1, %ymm1", "alu"),
    ("vextractf128\t$1, %ymm15, %xmm2", "alu"),
    ("vmovups\t-4096(%rdi,%rax,4), %zmm15", "load"),
    ("vbroadcastss\t(%rsi), %ymm13", "load"),
    ("vmovups\t464(%rsp), %ymm1", "load"),
    ("vmovups\t%zmm17, -9216(%rdi,%rax,4)", "store"),
    ("vmovups\t%ymm1, -9216(%rdx)", "store"),
    ("vmovaps\t%ymm8, %ymm4", "move"),
    ("vmovups\t%zmm1, (%rdi) {%k1}", "store"),  # masked store
    ("vmovups\t(%rdi), %zmm1 {%k1} {z}", "load"),  # masked load
    ("vmaskmovps\t%ymm1, %ymm2, (%rdi)", "store"),
    ("vmaskmovps\t(%rdi), %ymm2, %ymm1", "load"),
    ("vscatterqps\t%ymm5, (,%zmm6) {%k3}", "store"),
    ("vgatherdps\t(%rax,%zmm1,4), %zmm2 {%k1}", "load"),
    ("vpbroadcastd\t(%rax), %ymm3", "load"),
    ("vpextrd\t$1, %xmm0, (%rdi)", "store"),
    ("vextractf128\t$1, %ymm0, (%rdi)", "store"),
    ("vmovd\t%esi, %xmm12", "alu"),  # a transfer from a general register: not renamed away
    ("vmovss\t%xmm1, %xmm2, %xmm3", "alu"),  # merges two registers
    ("vbroadcastss\t%xmm0, %ymm1", "alu"),
    ("korw\t%k2, %k1, %k1", "mask"),
    ("movabsq\t$.LCPI6_23, %r15", "scalar"),
    ("addq\t$16, %rax", "scalar"),
    ("jg\t.LBB6_168", "scalar"),
]


def test_each_instruction_gets_its_hand_written_kind() -> None:
    for ins, expected in KINDS:
        assert kind(ins) == expected, ins


NEST = """\
f:
\tmovq\t%rdi, %rax
.LBB0_1:
\tvmovups\t(%rdi), %ymm0
.LBB0_2:
\tvroundps\t$9, %ymm0, %ymm1
\tvcvttps2dq\t%ymm0, %ymm1
\tvmulps\t%ymm1, %ymm0, %ymm0
\tvmovups\t%ymm0, (%rsi)
\tvmovups\t%ymm0, 32(%rsi)   # a comment
\taddq\t$8, %rax
\tjne\t.LBB0_2
\tvaddps\t%ymm0, %ymm0, %ymm0
\tjne\t.LBB0_1
.LBB0_3:
\tvroundps\t$9, %ymm0, %ymm1
\tvcvttps2dq\t%ymm0, %ymm1
\tvmovups\t%ymm1, (%rsi)
\tjne\t.LBB0_3
\tretq
"""


def test_only_innermost_loops_are_found_and_the_loop_with_most_stores_is_the_pixel_loop() -> None:
    loops = innermost_loops(NEST)
    assert [len(body) for body in loops] == [7, 4]  # .LBB0_2 and .LBB0_3; .LBB0_1 holds .LBB0_2
    assert loops[0][-1] == "jne\t.LBB0_2" and loops[0][4] == "vmovups\t%ymm0, 32(%rsi)"
    c = pixel_loop(NEST)
    assert c == {"alu": 3, "load": 0, "store": 2, "move": 0, "mask": 0, "scalar": 2, "alu_zmm": 0, "instructions": 7,
                 "lanes": 8, "pixels": 8}
    assert pixel_loop(NEST.replace("vcvttps2dq", "vcvtps2dq")) is None  # no exp's conversion: no pixel loop
    assert pixel_loop(NEST.replace("vroundps", "vaddps")) is None  # a conversion without a floor: not exp
    # the same labels in a second module (a second signature) are that module's own loops
    two = pixel_loop(NEST.replace("32(%rsi)", "(%rdx)\n\tvmovups\t%ymm0, 64(%rsi)"), NEST)
    assert two is not None and two["store"] == 3
    wide = census(["vroundps\t$9, %zmm1, %zmm2", "vaddps\t%zmm1, %zmm2, %zmm3", "vrndscaleps\t$9, %zmm1, %zmm4"])
    assert (wide["lanes"], wide["pixels"], wide["alu_zmm"]) == (16, 32, 3)  # two exps a pass: unrolled twice
    line = pixel_loop_line("forward", c)
    assert "one pass = 8 pixels (8-lane vectors): 3 vector ALU instructions (0.38 a pixel; 0 on zmm)" in line
    assert "2 stores" in line
    assert pixel_loop_line("backward", None) == "backward pixel loop: not found in the assembly"


def test_a_compiled_loop_is_counted_with_its_stores_and_the_targets_lanes() -> None:
    """A loop in the raster kernels' style (float32, unsigned index, three output rows, a
    floor and float-to-int conversion as exp's), compiled here with the project's options: the
    census finds it with the compile target's lanes, and three stores for each exp of a pass."""
    from numba import njit

    from ftgspp.runtime.jit import JIT, vector_lanes

    @njit(**{**JIT, "cache": False})
    def rows(a, out):
        n = np.uint64(a.shape[0])
        for i in range(n):
            x = a[i] * np.float32(1.5)
            e = np.float32(np.int32(np.floor(x)))
            out[i] = x - e
            out[n + i] = x * e
            out[np.uint64(2) * n + i] = e

    a = np.linspace(0, 9, 64, dtype=np.float32)
    out = np.zeros(3 * 64, np.float32)
    rows(a, out)
    assert np.array_equal(out[128:], np.floor(a * np.float32(1.5)))  # it ran as written
    c = pixel_loop("".join(rows.inspect_asm().values()))
    assert c is not None
    assert c["lanes"] == vector_lanes()
    assert c["store"] == 3 * (c["pixels"] // c["lanes"]) and c["alu"] >= 3
