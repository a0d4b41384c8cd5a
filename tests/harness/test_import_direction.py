"""The library never imports the harness or its frameworks (harness -> ftgspp only)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FORBIDDEN = {"harness", "hydra", "omegaconf", "mlflow"}


def _imported_top_level(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in {
            "import_module", "__import__"} and node.args and isinstance(node.args[0], ast.Constant):
            names.add(str(node.args[0].value).split(".")[0])
    return names


def test_ftgspp_does_not_import_harness_hydra_omegaconf_or_mlflow() -> None:
    files = sorted((ROOT / "ftgspp").rglob("*.py"))
    assert files
    offenders = {str(f.relative_to(ROOT)): sorted(_imported_top_level(f) & FORBIDDEN) for f in files}
    assert {f: bad for f, bad in offenders.items() if bad} == {}


def test_the_checker_sees_every_import_form(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text("import mlflow.tracking\nfrom hydra import compose\nimport importlib\n"
                   "def f():\n    from omegaconf import OmegaConf\n    importlib.import_module('harness.cli')\n")
    assert _imported_top_level(src) >= FORBIDDEN


# --- the renderer knows no method (methods -> render only) ------------------------------------
METHOD_MODULES = ("ftgspp.methods", "ftgspp.model")  # ftgspp/model.py held FreeTimeGS before ftgspp/methods/
METHOD_NAMES = ("FreeTime", "Spacetime", "DynamicGaussians", "GaussiansAt")


def _imported_modules(path: Path, package: str) -> set[str]:
    """Full names of the modules ``path`` (a module of ``package``) imports, in every form:
    ``import a.b``, ``from a.b import c`` (and ``a.b.c``), relative imports, ``import_module("a.b")``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, *([base] if base else [])])
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in {
            "import_module", "__import__"} and node.args and isinstance(node.args[0], ast.Constant):
            names.add(str(node.args[0].value))
    return names


def _method_imports(path: Path, package: str) -> list[str]:
    return sorted(m for m in _imported_modules(path, package)
                  if any(m == p or m.startswith(p + ".") for p in METHOD_MODULES))


def test_render_imports_no_method_and_names_none() -> None:
    """``ftgspp/render/`` imports nothing from ``ftgspp/methods/`` (nor the old ``ftgspp/model.py``)
    and names no method: a method brings its fused stage to the renderer, not the other way."""
    files = sorted((ROOT / "ftgspp" / "render").rglob("*.py"))
    assert files
    imports = {str(f.relative_to(ROOT)): _method_imports(f, "ftgspp.render") for f in files}
    assert {f: bad for f, bad in imports.items() if bad} == {}
    named = {str(f.relative_to(ROOT)): [n for n in METHOD_NAMES if n in f.read_text()] for f in files}
    assert {f: bad for f, bad in named.items() if bad} == {}


def test_freetime_is_a_method_plug_in_like_the_others() -> None:
    from ftgspp.methods import BUILTIN, method_class

    assert not (ROOT / "ftgspp" / "model.py").exists()
    for name, target in BUILTIN.items():
        assert target.startswith("ftgspp.methods."), (name, target)
        assert method_class(name).__module__ == target.partition(":")[0]
    assert (ROOT / "ftgspp" / "methods" / "freetime.py").is_file()
    assert method_class("freetime").__module__ == "ftgspp.methods.freetime"


def test_the_method_import_check_sees_every_form(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text("import ftgspp.model\nfrom ftgspp import methods\nfrom ..methods.base import GaussiansAt\n"
                   "import importlib\nimportlib.import_module('ftgspp.methods.stg')\nfrom ftgspp.render import sh\n")
    assert _method_imports(src, "ftgspp.render") == [
        "ftgspp.methods", "ftgspp.methods.base", "ftgspp.methods.base.GaussiansAt", "ftgspp.methods.stg",
        "ftgspp.model"]
