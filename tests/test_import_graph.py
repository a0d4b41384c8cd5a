"""No import cycles inside ``ftgspp`` or ``harness``, package ``__init__`` modules included, and
the harness wings import only downward.

Every ``import``/``from ... import`` of a project module counts, including the ones inside
functions: a lazy import that exists only to dodge a loop is still a loop in the design (two
modules that each need the other's pieces). Shared pieces belong in a module both can
import. ``from package import name`` is an edge to the submodule ``package.name`` when that
is a module, else to the package's ``__init__`` (where ``name`` is defined): a submodule that
takes a constant from its own package's ``__init__`` while the ``__init__`` imports the
submodule is a cycle like any other.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# harness wings and what each may import (besides itself and ftgspp); cli may import anything
WINGS = {
    "spec": set(),
    "tracking": set(),
    "analysis": {"spec"},
    "run": {"spec", "tracking"},
    "report": {"analysis", "spec", "tracking"},
}


def module_name(path: Path, package: Path) -> str:
    parts = path.relative_to(package.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: Path) -> dict[str, set[str]]:
    """``module -> {modules of the same package it imports}``."""
    modules = {module_name(p, package): p for p in package.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets.update(a.name for a in node.names if a.name in modules)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for a in node.names:
                    sub = f"{node.module}.{a.name}"
                    if sub in modules:
                        targets.add(sub)
                    elif node.module in modules:
                        targets.add(node.module)
        graph[name] = targets - {name}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as a list of modules (first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1 = on the stack, 2 = done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start)):
            return cycle
    return None


def test_the_cycle_finder_finds_a_planted_cycle(tmp_path: Path) -> None:
    pkg = tmp_path / "ftgspp"
    (pkg / "data").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "__init__.py").write_text("")
    (pkg / "data" / "load.py").write_text("from ftgspp.data.dynerf import read\n")
    (pkg / "data" / "dynerf.py").write_text("def read():\n    from ftgspp.data.load import Source\n")
    assert find_cycle(import_graph(pkg)) == ["ftgspp.data.dynerf", "ftgspp.data.load", "ftgspp.data.dynerf"]
    (pkg / "data" / "dynerf.py").write_text("def read():\n    pass\n")
    assert find_cycle(import_graph(pkg)) is None


def test_a_constant_taken_from_the_package_init_that_imports_the_module_is_a_cycle(tmp_path: Path) -> None:
    pkg = tmp_path / "ftgspp"
    (pkg / "render").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "render" / "__init__.py").write_text("EPS = 0.3\ndef render():\n    from ftgspp.render.project import p\n")
    (pkg / "render" / "project.py").write_text("from ftgspp.render import EPS\n")
    assert find_cycle(import_graph(pkg)) == ["ftgspp.render", "ftgspp.render.project", "ftgspp.render"]
    # importing a submodule through its package is an edge to the submodule, not to __init__
    (pkg / "render" / "project.py").write_text("from ftgspp.render import other\n")
    (pkg / "render" / "other.py").write_text("")
    assert find_cycle(import_graph(pkg)) is None


def test_ftgspp_has_no_import_cycles() -> None:
    cycle = find_cycle(import_graph(ROOT / "ftgspp"))
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_harness_has_no_import_cycles() -> None:
    cycle = find_cycle(import_graph(ROOT / "harness"))
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_harness_wings_import_only_downward() -> None:
    wrong = []
    for module, targets in import_graph(ROOT / "harness").items():
        wing = module.split(".")[1] if module.count(".") else ""
        if wing == "cli":
            continue
        for t in targets:
            other = t.split(".")[1] if t.count(".") else ""
            if other and other != wing and other not in WINGS.get(wing, set()):
                wrong.append(f"{module} -> {t}")
    assert not wrong, "upward or sideways imports: " + "; ".join(sorted(wrong))


def test_the_harness_has_no_loose_modules() -> None:
    loose = sorted(p.name for p in (ROOT / "harness").glob("*.py") if p.name != "__init__.py")
    assert loose == [], f"modules directly in harness/ (put them in a wing): {loose}"
    assert set(WINGS) | {"cli"} == {p.name for p in (ROOT / "harness").iterdir() if (p / "__init__.py").is_file()}
