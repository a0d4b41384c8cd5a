"""The paper's side of a verdict row: its numbers, its own evidence per dataset and its effects
(``paper_columns``, from the statement's register entry), and the paper's size judged beside
ours (``size_text``). Split from ``analysis.verdicts``, which re-exports both."""

from __future__ import annotations

import math

import numpy as np

from harness.analysis import stats
from harness.spec.paper_register import Statement


def paper_columns(statement: Statement | None, test: str) -> dict[str, str]:
    """The paper's numbers, its own evidence per dataset and its effects (for the size judgement
    and the forest plot), from the statement's register entry."""
    if statement is None:
        return {"paper_statement": "", "paper_source": "", "paper_numbers": "", "paper_evidence": "",
                "paper_effects": ""}
    numbers, evidence, effects = [], [], []
    for r in statement.numbers:
        note = f" ({r.note})" if r.note else ""
        if test == "variance" and r.a_std is not None and r.b_std is not None and r.a is None:
            numbers.append(f"{r.dataset}: SD {r.b_std:g} → {r.a_std:g} ({r.n} runs){note}")
            effects.append(f"{r.dataset}={r.a_std / r.b_std:.6g}")
            evidence.append(f"{r.dataset}: {_f_test(r.a_std, r.b_std, r.n)}")
            continue
        if test == "spread" and r.a_std is not None and r.a is None:
            numbers.append(f"{r.dataset}: SD {r.a_std:g} ({r.n} runs){note}")
            effects.append(f"{r.dataset}={r.a_std:.6g}")
            continue
        if r.a is None:
            numbers.append(f"{r.dataset}: {r.note or 'no number'}")
            continue
        pm = (lambda v, sd: f"{v:g} ± {sd:g}" if sd is not None else f"{v:g}")
        numbers.append((f"{r.dataset}: {pm(r.b, r.b_std)} → {pm(r.a, r.a_std)}" + (f" ({r.n} runs)" if r.n else "")
                        if r.b is not None else f"{r.dataset}: {r.a:+g}") + note)
        effects.append(f"{r.dataset}={r.effect:.6g}")
        if r.b is not None:
            ev = stats.paper_evidence(r.a, r.b, r.a_std, r.b_std, r.n)
            evidence.append(f"{r.dataset}: {ev.effect:+.2f}, " + (
                "no spread reported for this configuration" if math.isnan(ev.p) else
                f"p = {ev.p:.2g} ({ev.how}): {'distinguishable' if ev.p < stats.ALPHA else 'not distinguishable'}"
                " from its own spread"))
    return {"paper_statement": statement.statement, "paper_source": statement.source,
            "paper_numbers": "; ".join(numbers), "paper_evidence": "; ".join(evidence),
            "paper_effects": ";".join(effects)}


def _f_test(a_std: float, b_std: float, n: int | None) -> str:
    """The paper's SD ratio against chance for its n (a two-sided F-test on its SDs)."""
    if not n:
        return "no run count reported"
    from scipy import stats as sps

    f = (a_std / b_std) ** 2
    p = 2 * min(sps.f.cdf(f, n - 1, n - 1), sps.f.sf(f, n - 1, n - 1))
    return f"SD ratio {a_std / b_std:.2f}, F-test p = {p:.2g} ({'distinguishable' if p < stats.ALPHA else 'not distinguishable'})"


def size_text(effects: str, effect: float, low: float, high: float, test: str = "mean") -> str:
    """Per dataset of the paper: its effect inside our 95% CI ("as large as the paper's"); else,
    read along the paper's direction (away from 0, or from 1 for an SD ratio), ours "smaller" or
    "larger than the paper's" — or "opposite direction" when our effect has the other sign."""
    out = []
    centre = 1.0 if test == "variance" else 0.0
    for part in filter(None, str(effects or "").split(";")):
        dataset, value = part.rsplit("=", 1)
        v = float(value)
        if not (np.isfinite(low) and np.isfinite(high)):
            continue
        paper, ours = np.sign(v - centre), np.sign(effect - centre)
        if low <= v <= high:
            judged = "as large as the paper's"
        elif paper != 0 and ours == -paper:
            judged = "opposite direction"
        else:  # the paper's effect beyond our CI on its own side: ours is smaller
            beyond = v > high if paper >= 0 else v < low
            judged = "smaller than the paper's" if beyond and paper != 0 else "larger than the paper's"
        out.append(f"{dataset}: {judged}")
    return "; ".join(out)
