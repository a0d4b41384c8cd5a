"""No import cycle among the modules of ``ftgspp/diagnostics/``: an AST import graph (function-level
imports included) must be acyclic, and each module imports first in a fresh interpreter.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "ftgspp" / "diagnostics"
MODULES = sorted(f"ftgspp.diagnostics.{p.stem}" for p in PKG.glob("*.py") if p.stem not in ("__init__", "__main__"))


def imports_of(path: Path) -> set[str]:
    """Every ``ftgspp.*`` module ``path`` imports anywhere (top level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found |= {f"{node.module}.{a.name}" for a in node.names}  # `from ftgspp.diagnostics import figures`
    return {m for m in found if m in MODULES}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of nodes, or None (depth-first search)."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(node: str, stack: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [node, nxt] if nxt in stack else [node, nxt]
            if nxt not in state and (cyc := visit(nxt, [*stack, node])):
                return cyc
        state[node] = 2
        return None

    for n in sorted(graph):
        if n not in state and (cyc := visit(n, [])):
            return cyc
    return None


def test_cycle_finder_finds_a_planted_cycle():
    assert find_cycle({"a": {"b"}, "b": {"a"}}) is not None
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) is not None
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_diagnostics_modules_import_graph_is_acyclic():
    assert {"ftgspp.diagnostics.diagnose", "ftgspp.diagnostics.figures"} <= set(MODULES)
    graph = {m: imports_of(PKG / f"{m.rsplit('.', 1)[1]}.py") - {m} for m in MODULES}
    assert find_cycle(graph) is None, f"import cycle: {' -> '.join(find_cycle(graph) or [])}"


@pytest.mark.parametrize("module", MODULES)
def test_each_diagnostics_module_imports_first_in_a_fresh_interpreter(module):
    res = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-2000:]


def test_the_package_runs_as_the_diagnose_command():
    res = subprocess.run([sys.executable, "-m", "ftgspp.diagnostics", "--help"], capture_output=True, text=True)
    assert res.returncode == 0 and "ftgspp diagnose" in res.stdout
