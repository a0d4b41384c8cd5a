"""The repository is self-contained: a clone with nothing beside it can run its tests.

Nothing the project runs (code, tests, Makefile, configs, CI) may read from a path
outside the repository, such as a sibling ``shared/`` folder of a development checkout.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("*.py", "*.yaml", "*.yml", "*.toml", "*.cfg", "Makefile", "run")
SKIP_DIRS = {".git", ".venv", "node_modules", "outputs", "multirun", "mlruns", "data"}
SIBLING = "shar" + "ed"  # spelled in two pieces so this file does not match its own pattern
# "../<sibling>", '"..", "<sibling>"' or '"..") / "<sibling>"': the sibling folder of a dev checkout
OUTSIDE = re.compile(r"""\.\./SIB|["']\.\.["']\s*\)?\s*[,/]\s*["']SIB["']""".replace("SIB", SIBLING))


def project_files() -> list[Path]:
    files = []
    for pattern in SCANNED:
        for path in ROOT.rglob(pattern):
            if not SKIP_DIRS.intersection(path.relative_to(ROOT).parts) and path.is_file():
                files.append(path)
    return files


def test_the_pattern_catches_the_old_lpips_path() -> None:
    old = f'LPIPS_REF_DIR = Path(__file__).resolve().parents[1] / ".." / "{SIBLING}" / "data" / "lpips_ref"'
    assert OUTSIDE.search(old) and OUTSIDE.search(f"cp ../{SIBLING}/data/x .")
    assert not OUTSIDE.search(f"{SIBLING} axis") and not OUTSIDE.search(f'tmp_path / "{SIBLING}x"')


def test_nothing_reads_from_outside_the_repository() -> None:
    offenders = [f"{p.relative_to(ROOT)}:{i}" for p in project_files()
                 for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1) if OUTSIDE.search(line)]
    assert offenders == []


def test_lpips_reference_images_ship_with_their_provenance() -> None:
    ref = ROOT / "tests" / "assets" / "lpips_ref"
    for name in ("ex_ref.png", "ex_p0.png", "ex_p1.png", "expected.json", "README.md"):
        assert (ref / name).is_file(), name
    readme = (ref / "README.md").read_text()
    assert "BSD" in readme and "PerceptualSimilarity" in readme
