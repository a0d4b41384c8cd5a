"""The code's layout reads at a glance: a family of files is a package, two modules never share a
name in different folders, and no module outgrows a top-to-bottom read.

Allowed exceptions are named here, each with its reason: ``__init__``/``__main__``/``conftest``
are Python's and pytest's fixed names; the Numba kernel files keep a kernel and its
hand-written backward side by side (docs/design.md §3).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("ftgspp", "harness", "benchmarks", "scripts", "tests")
FIXED_NAMES = {"__init__.py", "__main__.py", "conftest.py"}
MAX_LINES = 400
KERNEL_FILES = {"ftgspp/render/cpu_kernels.py", "ftgspp/render/prepare_kernels.py"}


def python_files() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py") if "__pycache__" not in p.parts)


def same_names(paths: list[Path]) -> dict[str, list[str]]:
    """Module file names that occur in more than one folder (fixed names left out)."""
    seen: dict[str, list[str]] = defaultdict(list)
    for p in paths:
        if p.name not in FIXED_NAMES:
            seen[p.name].append(p.relative_to(ROOT).as_posix())
    return {name: where for name, where in seen.items() if len(where) > 1}


def too_long(paths: list[Path], limit: int = MAX_LINES) -> list[str]:
    """Modules over ``limit`` lines, kernel files and tests left out."""
    out = []
    for p in paths:
        rel = p.relative_to(ROOT).as_posix()
        if rel in KERNEL_FILES or rel.startswith("tests/"):
            continue
        n = len(p.read_text().splitlines())
        if n > limit:
            out.append(f"{rel}: {n} lines")
    return out


def test_no_two_modules_share_a_name() -> None:
    assert same_names(python_files()) == {}


def test_no_module_outgrows_a_read() -> None:
    assert too_long(python_files()) == []


def test_the_checks_catch_a_planted_duplicate_and_a_long_module(tmp_path: Path) -> None:
    a, b = ROOT / "ftgspp" / "model.py", ROOT / "harness" / "spec" / "model.py"  # b need not exist
    assert same_names([a, b]) == {"model.py": ["ftgspp/model.py", "harness/spec/model.py"]}
    assert too_long([ROOT / "ftgspp" / "trainer.py"], limit=10) != []
    assert too_long([ROOT / "ftgspp" / "render" / "cpu_kernels.py"], limit=10) == []
