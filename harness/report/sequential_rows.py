"""The rows a study runs until decided: their verdicts come from the sequential replay, not the
report's fixed-n Holm (issue 57; docs/sequential.md).

A study whose profile has a ``sequential:`` block adds runs round by round while a claim is
undecided (``study decide``); a fixed-n test on the runs it stopped at would read a stopping rule
that looked at the data as if it had not (its error rate is not α). So each claim of the study's
sequential design (``analysis.sequential_study.design``) is decided here by the same replay
``study decide`` prints (``sequential_study.decide``: α-spending looks, one Holm-type recycling per
family, at the claim's share of its group's α), and ``annotate`` writes that decision into the
study's claim rows:

- ``seq_verdict``: reproduced / contradicted / equivalent when a look rejected, else inconclusive
  (still running, or stopped at its cap);
- ``seq_alpha``: the α its family's sequential claims of this study hold (``Design.alpha``);
- ``seq_text``: one clause for the verdict's "why" (the look, its count, the rule, or what a
  fixed design would need at the cap);
- ``seq_needed``: at the cap, the runs per arm a fixed design would need at its share.

``verdicts.decide`` then leaves those rows out of their group's fixed-n Holm, which runs at α
less every sequential share of the group (a Bonferroni split between the parts: the group's
family-wise error is at most the sum), so deciding them never borrows α the other rows hold.
A study without a sequential plan gets no columns and is decided as before.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats as sps

from ftgspp.errors import InputError
from harness.analysis import sequential as Q, sequential_study as S, stats, verdicts as V
from harness.spec.paper_register import Register
from harness.spec.study_files import list_studies, load_study
from harness.spec.study_schema import StudySpec

COLUMNS = ("seq_verdict", "seq_alpha", "seq_text", "seq_needed")
PROFILE = "quick"  # the profile the reports are made with (``make reports``)


def sequential_profile(study: StudySpec, profile: str | None) -> str | None:
    """The profile whose sequential plan decides the study's rows: ``profile`` (else the quick
    one) when it has a ``sequential:`` block; None when it has none."""
    name = profile or PROFILE
    prof = study.profiles.get(name)
    return name if prof is not None and prof.sequential is not None else None


def _text(o: S.Outcome, alpha: float, spending: str, d: S.Design | None = None) -> str:
    """One clause: what the replay decided for this claim."""
    c, dec = o.claim, o.decision
    rule = f"runs until decided ({S.SPENDING_NAMES[spending]} spending, α {alpha:.3g} for this study's claims" \
           " of the family)"
    if dec is None:
        return f"{rule}: no look yet (the first needs {o.needs} {c.unit})"
    if o.status == Q.DECIDED:
        p = max(dec.p[Q.HYPOTHESES.index(h)] for h in dec.rejected)
        return f"{rule}: the {' and '.join(dec.rejected)} test rejected at look {dec.look} ({dec.n} {c.unit}, p = {p:.2g})"
    if o.status == Q.CONTINUE:
        return f"{rule}: undecided at look {dec.look} ({dec.n} {c.unit}); the next look needs {o.needs}"
    need = (f"a fixed design at its share needs about {int(dec.runs_needed)} {c.unit}" if dec.runs_needed < 1e9
            else "a fixed design's count cannot be estimated from these runs")
    hours = d.hours(int(dec.runs_needed) * c.plan.arms) if d is not None and dec.runs_needed < 1e9 else float("nan")
    if hours == hours:  # not NaN: the profile states its run_seconds
        need += f", {hours:.3g} CPU h at {d.profile.run_seconds:g} s a run (`study decide` prints the command)"
    return f"{rule}: stopped at its cap undecided ({dec.n} {c.unit}); {need}"


def design_of(study: StudySpec, register: Register, studies_dir: Path | None = None,
              profile: str | None = None) -> S.Design | None:
    """The study's sequential design under ``profile`` (else the quick one); None when it has none
    (no ``sequential:`` block, no counted mean claim the profile runs). A design the study file
    cannot run (``sequential_study.DesignError``) is one error line, never a silent fixed-n."""
    name = sequential_profile(study, profile)
    if name is None:
        return None
    try:
        return S.design(study, name, register,
                        lambda: {n: load_study(n, studies_dir) for n in list_studies(studies_dir)})
    except S.DesignError:
        raise
    except InputError:
        return None  # nothing of it runs until decided under this profile


def claim_ids(d: S.Design | None) -> frozenset[str]:
    """The ids of the design's claims (none without one): ``verdicts.evaluate(pooled=...)``."""
    return frozenset(c.spec.id for c in d.claims) if d is not None else frozenset()


def _at_look(o: S.Outcome) -> dict:
    """The row's effect, naive 95% interval and n on the runs its latest look read (the look that
    decided it, or the last one; before any look, the runs so far when there are two)."""
    c, r = o.claim, o.runs
    n = o.decision.n if o.decision is not None else min(r.n, c.plan.n_max)
    if n < 2:
        return {"effect": float("nan"), "ci_low": float("nan"), "ci_high": float("nan"), "n": f"{n} {c.unit}"}
    a = r.a[:n]
    if r.b is None:
        test = sps.ttest_1samp(a, 0.0)
        effect = float(np.mean(a))
    else:
        test = sps.ttest_ind(a, r.b[:n], equal_var=False)
        effect = float(np.mean(a) - np.mean(r.b[:n]))
    ci = test.confidence_interval(1 - stats.ALPHA)
    return {"effect": effect, "ci_low": float(ci.low), "ci_high": float(ci.high), "n": f"{n} {c.unit}"}


def annotate(frame: pd.DataFrame, d: S.Design | None, runs: pd.DataFrame, spending: str = "obf") -> pd.DataFrame:
    """``frame`` (the study's ``verdicts.evaluate`` rows, its design's claims unsplit:
    ``evaluate(pooled=...)``) with ``COLUMNS`` for every claim of the design ``d`` (module
    docstring); unchanged without one. Each such row shows its effect, interval and n at its
    latest look (``_at_look``) and enters its family whatever its fixed-n test said (a fixed-n
    test of a claim run until decided may wait for instances the replay does not read).
    ``runs``: the study's runs frame with instance columns and derived metrics."""
    if d is None or frame.empty:
        return frame
    out = frame.copy()
    for col, empty in zip(COLUMNS, ("", float("nan"), "", float("nan"))):
        out[col] = empty
    for fam in S.decide(d, runs, spending):
        alpha = d.alpha(fam.name)
        for o in fam.outcomes:
            rows = out.index[out.id == o.claim.spec.id]  # the pooled row (the design's claims are never split)
            decided = o.status == Q.DECIDED and o.decision is not None
            needed = o.decision.runs_needed if o.decision is not None and o.status == Q.AT_CAP else float("nan")
            for i in rows:
                if out.at[i, "verdict"] not in V.DECIDED:  # e.g. its fixed-n test waits for instances
                    out.at[i, "note"] = ""
                out.at[i, "verdict"] = V.INCONCLUSIVE  # until decide() takes the replay's verdict
                look = _at_look(o)
                for key, value in look.items():
                    out.at[i, key] = value
                out.at[i, "ci_adj_low"], out.at[i, "ci_adj_high"] = look["ci_low"], look["ci_high"]
                out.at[i, "ci_adj_level"] = 1 - stats.ALPHA  # naive: no repeated-confidence interval
                if V.INTERVAL in out:
                    out.at[i, V.INTERVAL] = None  # the fixed-n test's interval is not this row's
                test = "paired t" if o.claim.paired else "Welch t" if o.claim.spec.b else "one-sample t"
                out.at[i, "method"] = f"run until decided ({test} at its latest look)"
                out.at[i, "seq_verdict"] = o.decision.verdict if decided else V.INCONCLUSIVE
                out.at[i, "seq_alpha"] = alpha
                out.at[i, "seq_text"] = _text(o, alpha, spending, d)
                out.at[i, "seq_needed"] = needed
    return out
