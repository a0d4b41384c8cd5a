"""Every citation resolves: a repository path, a module named in double backticks, or a section
sign cited in code, docs or study files points at something that exists.

Four kinds of citation are checked, in every tracked text file but the generated reports and
the history pages (which record what was true when they were written):

- **paths** — ``ftgspp/render/cpu.py``, ``studies/secret5.yaml``, ``docs/design.md``: the file or
  folder exists (a path with a placeholder such as ``<name>``, ``NAME`` or ``*`` must match
  something as a glob); not in ``tests/``, whose paths are mostly the ones a test builds;
- **modules** — ``harness.run.task.RunTask`` (in double backticks, in Markdown also in single
  ones, or after ``python -m``) or, inside ``harness/``, a wing-relative ``analysis.claim_tests``:
  the longest prefix that is a module of this repository exists, the next name is defined at its
  top level (a class, function, assignment or import) and a name after a class is one of its
  members;
- **sibling files** — a bare ``render.py`` in a module's docstring is a file of the same folder;
- **sections** — ``docs/design.md §4``: the document has a heading numbered 4.
"""

from __future__ import annotations

import ast
import functools
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOP = ("ftgspp", "harness", "tests", "docs", "studies", "conf", "benchmarks", "scripts", "reports")
WINGS = ("spec", "tracking", "analysis", "run", "report", "cli")
SUFFIXES = "py|md|yaml|yml|csv|json|png|sh|toml|txt|jsonl|npy|tex|pt"
# history and generated pages: they record what was true when they were written
NOT_CHECKED = ("reports/", "docs/benchmarks-history.md")
TEXT = (".py", ".md", ".yaml", ".yml", ".toml", ".sh", ".cfg")

PATH = re.compile(rf"(?<![\w./<-])((?:{'|'.join(TOP)})/[\w./<>*{{}}-]*?(?:\.(?:{SUFFIXES})\b|/(?=[\s`'\")\],;:]|$)))")
MODULE = re.compile(r"``((?:ftgspp|harness|" + "|".join(WINGS) + r")(?:\.\w+)+)(?:\(\))?``")
MD_MODULE = re.compile(r"(?<!`)`((?:ftgspp|harness)(?:\.\w+)+)(?:\(\))?`(?!`)")  # Markdown's inline code
RUN_MODULE = re.compile(r"python3? -m ((?:ftgspp|harness)(?:\.\w+)*)")
SIBLING = re.compile(r"``([a-z_]\w*\.py)``")
SECTION = re.compile(r"((?:docs/)?[\w-]+\.md)\)?`*\)? ?§ ?(\d+)")
# the section sign and double backticks, spelled so that this file's planted citations are not its own
SIGN, TICKS = "\u00a7", "`" * 2
PLACEHOLDER = re.compile(r"<[^>]*>|\b[A-Z]{3,}\b|\*|\{[^}]*\}")


def tracked_files() -> list[Path]:
    out = subprocess.run(["git", "-C", str(ROOT), "ls-files"], capture_output=True, text=True, check=True).stdout
    return [ROOT / f for f in out.split() if f.endswith(TEXT) and not f.startswith(NOT_CHECKED)
            and f not in NOT_CHECKED and (ROOT / f).is_file()]


def path_exists(cited: str) -> bool:
    cited = cited.rstrip("/.")
    if PLACEHOLDER.search(cited):
        pattern = PLACEHOLDER.sub("*", cited)
        return any(ROOT.glob(pattern))
    return (ROOT / cited).exists()


@functools.lru_cache(maxsize=None)
def top_level_names(path: Path) -> frozenset[str]:
    """Names a module defines at its top level (or a package's ``__init__``), with class members
    as ``Class.member``."""
    names: set[str] = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
            if isinstance(node, ast.ClassDef):
                for sub in node.body:
                    if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        names.add(f"{node.name}.{sub.name}")
                    elif isinstance(sub, ast.AnnAssign) and isinstance(sub.target, ast.Name):
                        names.add(f"{node.name}.{sub.target.id}")
                    elif isinstance(sub, ast.Assign):
                        names |= {f"{node.name}.{t.id}" for t in sub.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.If, ast.Try)):  # names defined under a guard count too
            for sub in ast.walk(node):
                if isinstance(sub, (ast.FunctionDef, ast.ClassDef)):
                    names.add(sub.name)
                elif isinstance(sub, ast.Assign):
                    names |= {t.id for t in sub.targets if isinstance(t, ast.Name)}
    return frozenset(names)


def module_resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    if parts[0] in WINGS:  # a wing-relative name inside the harness (``analysis.claim_tests``)
        parts = ["harness", *parts]
    for n in range(len(parts), 0, -1):
        base = ROOT.joinpath(*parts[:n])
        module = base.with_suffix(".py") if base.with_suffix(".py").is_file() else base / "__init__.py"
        if not module.is_file():
            continue
        rest = parts[n:]
        names = top_level_names(module)
        if not rest:
            return True
        if rest[0] not in names:
            return False
        members = {name.split(".", 1)[1] for name in names if name.startswith(rest[0] + ".")}
        return len(rest) == 1 or not members or rest[1] in members  # a class's member, when it is a class
    return False


def section_exists(doc: str, number: str) -> bool:
    path = ROOT / doc if (ROOT / doc).is_file() else ROOT / "docs" / doc
    if not path.is_file():
        return False
    return re.search(rf"^#+ {number}[.\s]", path.read_text(), flags=re.M) is not None


def broken_citations(files: list[tuple[str, str]]) -> list[str]:
    """Every citation of ``files`` ((path relative to the repository, text)) that does not resolve."""
    bad: list[str] = []
    for rel, body in files:
        folder = (ROOT / rel).parent
        for lineno, line in enumerate(body.splitlines(), 1):
            for cited in PATH.findall(line) if not rel.startswith("tests/") else ():  # tests build paths
                if not path_exists(cited):
                    bad.append(f"{rel}:{lineno}: path {cited}")
            dotted_names = MODULE.findall(line) + RUN_MODULE.findall(line)
            if rel.endswith(".md"):
                dotted_names += MD_MODULE.findall(line)
            for dotted in dotted_names:
                if dotted.split(".")[0] in WINGS and not rel.startswith(("harness/", "docs/", "tests/harness/")):
                    continue  # ``run.x`` outside the harness is not a harness name
                if not module_resolves(dotted):
                    bad.append(f"{rel}:{lineno}: module {dotted}")
            if rel.endswith(".py") and not rel.startswith("tests/"):
                bad += [f"{rel}:{lineno}: file {name}" for name in SIBLING.findall(line)
                        if not (folder / name).is_file() and not (folder.parent / name).is_file()]
            for doc, number in SECTION.findall(line):
                if not section_exists(doc, number):
                    bad.append(f"{rel}:{lineno}: section {doc} §{number}")
    return bad


def test_every_citation_resolves() -> None:
    bad = broken_citations([(p.relative_to(ROOT).as_posix(), p.read_text()) for p in tracked_files()])
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("text, kind", [
    (f"see {TICKS}harness/tracking.py{TICKS} for the client", "path harness/tracking.py"),
    ("the spread split by source (harness/variance.py)", "path harness/variance.py"),
    (f"leases ({TICKS}harness.lease{TICKS})", "module harness.lease"),
    (f"each claim ({TICKS}analysis.claims{TICKS})", "module analysis.claims"),
    (f"{TICKS}harness.run.task.NoSuchThing{TICKS}", "module harness.run.task.NoSuchThing"),
    (f"{TICKS}harness.run.task.RunTask.no_such_member{TICKS}", "module harness.run.task.RunTask.no_such_member"),
    ("workers run python -m " + "ftgspp.data.synthetic_pool", "module ftgspp.data.synthetic_pool"),
    (f"timed by {TICKS}no_such_timing.py{TICKS}", "file no_such_timing.py"),
    ("conventions: docs/design.md " + SIGN + "99", "section docs/design.md " + SIGN + "99"),
])
def test_a_planted_bad_citation_fails(text: str, kind: str) -> None:
    # cited from inside the harness: wing-relative names count there
    assert broken_citations([("harness/run/_planted.py", f'"""{text}"""\n')]) == [f"harness/run/_planted.py:1: {kind}"]


def test_markdown_inline_code_is_checked_too() -> None:
    assert broken_citations([("docs/design.md", "read `harness.spec.files.load_study`")]) == \
        ["docs/design.md:1: module harness.spec.files.load_study"]
    assert broken_citations([("docs/design.md", "read `harness.spec.study_files.load_study`")]) == []


def test_good_citations_pass() -> None:
    text = ('"""``harness.run.task.RunTask``, ``analysis.verdicts``, ftgspp/render/cpu.py, ``task.py``,\n'
            "``harness.run.task.RunTask.__call__``, python -m ftgspp.data.synthetic,\n"
            'reports/<name>/runs.csv, docs/design.md ' + SIGN + '4, studies/secret5.yaml"""\n')
    assert broken_citations([("harness/run/_planted.py", text)]) == []
