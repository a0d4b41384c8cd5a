"""The design of the studies in one paragraph, for the top of ``reports/index.md`` (issue 57):
which studies draw scene instances and how many, what the instance-level tests leave out, which
studies run their mean claims until decided and with what looks and spending. Read from the
study files, so the page names the design its verdicts were decided under.
"""

from __future__ import annotations

from pathlib import Path

from harness.analysis import sequential as Q, verdicts as V
from harness.spec.instances import PILOT
from harness.spec.study_files import list_studies, load_study

PROFILE = "quick"


def _studies(n: int) -> str:
    return f"{n} study" if n == 1 else f"{n} studies"


def design_paragraph(studies_dir: Path | None = None, profile: str = PROFILE) -> list[str]:
    """``["**Design.** ...", ""]``; no lines when no study draws instances or runs until decided."""
    drawn: dict[int, list[str]] = {}  # instances per scene -> studies drawing that many (their largest)
    plans: dict[str, list[str]] = {}  # a plan's text -> studies
    for name in list_studies(studies_dir):
        prof = load_study(name, studies_dir).profiles.get(profile)
        if prof is None:
            continue
        counts = {}
        for s in prof.scenes:
            counts[s.base] = max(counts.get(s.base, 1), s.instance + 1)
        if max(counts.values(), default=1) > 1:
            drawn.setdefault(max(counts.values()), []).append(name)
        seq = prof.sequential
        if seq is not None:
            keys = {k: getattr(seq, k) for k in ("first", "per_round", "rounds") if getattr(seq, k) is not None}
            looks = ", ".join(map(str, Q.Plan(**keys).schedule()))
            plans.setdefault(looks, []).append(name)
    if not drawn and not plans:
        return []
    parts = []
    if drawn:
        which = "; ".join(f"{', '.join(f'`{n}`' for n in names)}: {k} (instance {PILOT} and {k - 1} fresh)"
                          for k, names in sorted(drawn.items(), reverse=True))
        parts.append(f"method claims (mean, contrast, interaction) take the scene instance as their unit: "
                     f"{_studies(sum(map(len, drawn.values())))} draw every scene a counted method claim uses "
                     f"as several synthetic instances ({which}); instance {PILOT}, the scene as written, where the "
                     "claims were explored, is their pilot and enters no instance-level test, and a fresh "
                     "instance runs one seed; a claim with the seed as its unit (run-to-run, a spread) reads the "
                     "scene as written only")
    if plans:
        which = "; ".join(f"{', '.join(f'`{n}`' for n in names)} at {looks} fresh instances"
                          for looks, names in plans.items())
        parts.append(f"the counted mean claims of {_studies(sum(map(len, plans.values())))} run until "
                     f"decided ({which}; O'Brien–Fleming α-spending, each study's claims holding their share "
                     "of their family's α; `study decide`), every other row is decided at fixed n by one "
                     "Holm procedure per family over every study at the α the sequential rows leave")
    return [f"**Design.** {'. '.join(p[0].upper() + p[1:] for p in parts)} (docs/sequential.md).", ""]


def family_text(rows) -> str:
    """One group's family line from its counted rows (``verdicts.decide`` output): its fixed-n
    Holm's text, and how many rows run until decided with the α they hold; "" when none."""
    if not len(rows):
        return ""
    seq = V.sequential_rows(rows)
    text = next((f for f in rows[~seq].family if f), "")
    if not seq.any():
        return text
    held = V.held_shares(rows[seq])
    part = (f"{int(seq.sum())} rows of {_studies(len(held))} run until decided, holding α {float(held.sum()):.3g}"
            " (docs/sequential.md)")
    return f"{text}; {part}" if text else part
