"""The repository explains itself: every design document the code cites is in the repository."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_cited_document_exists_and_every_section_cited_is_there() -> None:
    design = (ROOT / "docs" / "design.md").read_text()
    sections = set(re.findall(r"^## (\d+)\.", design, flags=re.M))
    missing, bad = [], []
    for path in [*ROOT.glob("ftgspp/**/*.py"), *ROOT.glob("harness/**/*.py"), *ROOT.glob("conf/**/*.yaml"),
                 *ROOT.glob("tests/**/*.py"), ROOT / "README.md"]:
        text = path.read_text()
        for doc in re.findall(r"(?<![\w/.])(docs/[\w-]+\.md|[A-Z][A-Z_]+\.md)\b", text):
            if not (ROOT / doc).is_file() and not (ROOT / "reports" / doc).is_file() and \
                    not (ROOT / "docs" / doc).is_file():
                missing.append(f"{path.relative_to(ROOT)} cites {doc}")
        bad += [f"{path.relative_to(ROOT)}: §{n}" for n in re.findall(r"docs/design\.md §(\d+)", text)
                if n not in sections]
    assert not missing and not bad, missing + bad
