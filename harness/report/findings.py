"""``reports/findings.json``: every number ``reports/FINDINGS.md`` may cite, made from the reports.

``collect_findings(root)`` reads the generated files under ``root`` (each study's
``summary.csv``, ``runs.csv``, ``variance.csv``, ``ladders.csv``, ``speed_accuracy_smallest.csv``,
``method_comparison.csv``, the budget pages' ``budget.csv`` and the index's ``claims.csv``) and names every value: ``ablation.claims.flow_improves.effect``,
``secret5.psnr.cc.studio.mean``, ``stability.psnr.diff.ftgspp.base-speed4`` (the difference of
two cells' means), ``secret4.median.relocated_total.mcmc.studio`` (the median, ``min`` or
``max`` over a cell's finished runs of any logged number, tabled or not; a scene's fresh instances
are one cell, ``studio@fresh``),
``ablation.paper.flow_improves.DyNeRF.a`` (the paper's numbers as the study file states
them), ... ``write_findings`` saves them as JSON.

FINDINGS.md cites a number with the key it comes from, in an HTML comment right after it
(invisible when rendered): ``+0.77<!--ablation.claims.flow_improves.effect-->``; ``|abs``
after the key cites the magnitude. ``check`` returns every problem:

- a decimal number without a key (whole numbers without one are settings: "5 seeds", "20,000
  Gaussians"; a whole number *with* a key is checked like any other: ``1,546<!--key-->``);
- an unknown key, or a number the data does not hold at the precision it is printed with;
- a direction the sentence states against the sign of the number it cites: "colour correction
  lowers the spread (×1.61<!--…effect-->)" fails, since an SD ratio above 1 raises it. The
  direction is the nearest verb before the number in its sentence (``UP`` / ``DOWN``), turned
  round by a negation just before it; an effect is read against 0, an SD ratio against 1.

A test runs it on the committed files, so FINDINGS.md cannot drift from the reports.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from harness.report.results import fresh_as_one

NUMBER = re.compile(r"(?<![\w.`/#-])([+\-−×]?\d+\.\d+)(?:<!--([\w.\-|:\[\]]+)-->)?")
WHOLE = re.compile(r"(?<![\w.,`/#×-])([+\-−]?\d{1,3}(?:,\d{3})+|[+\-−]?\d+)(?![\d.,]\d)<!--([\w.\-|:\[\]]+)-->")
UP = ("raises", "raise", "raised", "raising", "increases", "increase", "increased", "widens", "widen", "adds", "add",
      "improves", "improve", "higher", "larger", "more")
DOWN = ("lowers", "lower", "lowered", "lowering", "reduces", "reduce", "reduced", "narrows", "narrow", "cuts", "cut",
        "shrinks", "shrink", "less", "smaller", "fewer", "drops", "costs", "loses")
NEGATIONS = ("not", "no", "never", "neither", "nor", "without")
SIGNED = (".effect",)  # claims' effects: the direction a sentence may state (CI bounds straddle 0)


def _slug(name: object) -> str:
    """A key part from a table row's or dataset's name: "hardware (kernel dispatch)" -> hardware_kernel_dispatch;
    a whole float as an integer (5000.0 -> 5000)."""
    if isinstance(name, float) and name.is_integer():
        name = int(name)
    return re.sub(r"[^\w\-]+", "_", str(name)).strip("_")


def _put(out: dict[str, float], key: str, value: object) -> None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return
    if math.isfinite(v):
        out[key] = v


def _summary(study: str, path: Path, out: dict[str, float]) -> None:
    df = pd.read_csv(path)
    for r in df.itertuples():
        for col in ("mean", "std", "ci95"):
            _put(out, f"{study}.{r.metric}.{r.variant}.{r.scene}.{col}", getattr(r, col))
    for metric, sub in df.groupby("metric"):
        means = {(r.variant, r.scene): r.mean for r in sub.itertuples()}
        for (va, sa), (vb, sb) in itertools.permutations(means, 2):
            if sa == sb:
                _put(out, f"{study}.{metric}.diff.{sa}.{va}-{vb}", means[(va, sa)] - means[(vb, sb)])
            elif va == vb:
                _put(out, f"{study}.{metric}.diff.{va}.{sa}-{sb}", means[(va, sa)] - means[(vb, sb)])


def _table(study: str, path: Path, kind: str, keys: list[str], out: dict[str, float]) -> None:
    df = pd.read_csv(path)
    for _, r in df.iterrows():
        name = ".".join(_slug(r[k]) for k in keys)
        for col, value in r.items():
            if col not in keys:
                _put(out, f"{study}.{kind}.{name}.{col}", value)


def _medians(study: str, path: Path, out: dict[str, float]) -> None:
    df = pd.read_csv(path)
    done = fresh_as_one(df[df.status == "FINISHED"])  # a scene's fresh instances are one cell: <scene>@fresh
    skip = {"seed", "budget", "iterations", "lr.scale", "torch_threads", "instance"}
    cols = [c for c in done.select_dtypes("number").columns if c not in skip and not c.startswith("system/")]
    with np.errstate(over="ignore"):  # lifetimes of ungated Gaussians reach float32's max: inf is no finding
        for (variant, scene), cell in done.groupby(["variant", "scene"]):
            for col in cols:
                for stat in ("median", "min", "max"):
                    _put(out, f"{study}.{stat}.{col}.{variant}.{scene}", cell[col].agg(stat))


def _paper(out: dict[str, float], studies_dir: Path | None) -> None:
    """The paper's numbers as the register states them: ``paper.ab_flow.DyNeRF.a``."""
    from harness.spec.paper_register import load_register
    from harness.spec.study_files import STUDIES_DIR

    for s in load_register(Path(studies_dir or STUDIES_DIR)).statements:
        for row in s.numbers:
            ds = _slug(row.dataset)
            for field in ("a", "b", "a_std", "b_std", "n"):
                _put(out, f"paper.{s.id}.{ds}.{field}", getattr(row, field))
            if row.a is not None and row.b is not None:
                _put(out, f"paper.{s.id}.{ds}.effect", row.a - row.b)
            if row.a_std is not None and row.b_std:
                _put(out, f"paper.{s.id}.{ds}.sd_ratio", row.a_std / row.b_std)


def collect_findings(root: Path, studies_dir: Path | None = None) -> dict[str, float]:
    """Every named number under ``root`` (a reports folder), and the paper's numbers from the
    study files (``studies_dir``, default the repository's)."""
    out: dict[str, float] = {}
    _paper(out, studies_dir)
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        study = folder.name
        if (folder / "summary.csv").is_file():
            _summary(study, folder / "summary.csv", out)
        if (folder / "runs.csv").is_file():
            _medians(study, folder / "runs.csv", out)
        if (folder / "variance.csv").is_file():
            _table(study, folder / "variance.csv", "variance", ["component"], out)
        if (folder / "ladders.csv").is_file():
            _table(study, folder / "ladders.csv", "ladder", ["ladder", "scene", "variant"], out)
        if (folder / "speed_accuracy_smallest.csv").is_file():
            smallest = folder / "speed_accuracy_smallest.csv"  # one row per scene, or per scene and method
            methods = pd.read_csv(smallest).get("method", pd.Series(dtype=str))
            keys = ["scene", "method"] if methods.notna().any() else ["scene"]
            _table(study, smallest, "smallest", keys, out)
        if (folder / "speed_accuracy_smallest_psnr_cc.csv").is_file():
            _table(study, folder / "speed_accuracy_smallest_psnr_cc.csv", "smallest_cc", ["scene", "method"], out)
        if (folder / "method_comparison.csv").is_file():
            _table(study, folder / "method_comparison.csv", "methods", ["scene", "budget", "iterations"], out)
        for page in sorted(folder.glob("*/budget.csv")):  # study budget --out reports/budget
            _table(f"{study}.{_slug(page.parent.name)}", page, "budget", ["budget"], out)
        for page in sorted(folder.glob("*/settled.csv")):  # study prune --out reports/pruning
            _table(f"{study}.{_slug(page.parent.name)}", page, "keep", ["keep"], out)
    if (root / "claims.csv").is_file():  # the index's verdicts: corrected over every study
        for _, r in pd.read_csv(root / "claims.csv").iterrows():
            for col in ("effect", "ci_low", "ci_high", "ci_adj_low", "ci_adj_high", "sesoi", "p", "p_tost", "p_adj",
                        "p_tost_adj", "n_needed", "family_size"):
                _put(out, f"{r.study}.claims.{r.id}.{col}", r.get(col))
            if r.get("test") == "variance":  # an SD ratio: its direction is read against 1
                out[f"{r.study}.claims.{r.id}.centre"] = 1.0
    return out


def write_findings(root: Path, studies_dir: Path | None = None) -> Path:
    """``root/findings.json`` from the reports under ``root`` and the study files."""
    path = root / "findings.json"
    path.write_text(json.dumps(collect_findings(root, studies_dir), indent=1, sort_keys=True) + "\n")
    return path


def _stated_direction(before: str) -> int:
    """+1 / −1 for the nearest direction word of ``before`` (the sentence up to a number), turned
    round by a negation among the three words before it; 0 when it states none."""
    words = re.findall(r"[a-z']+", before.lower())
    for i in range(len(words) - 1, -1, -1):
        sign = 1 if words[i] in UP else -1 if words[i] in DOWN else 0
        if sign:
            negated = any(w in NEGATIONS or w.endswith("n't") for w in words[max(0, i - 3):i])
            return -sign if negated else sign
    return 0


def _sentence_before(body: str, start: int) -> str:
    """The text of the number's sentence before it (back to the last full stop, colon, semicolon or line)."""
    cut = max(body.rfind(mark, 0, start) for mark in (". ", ": ", "; ", "\n", "— "))
    return body[cut + 1:start]


def check(text: str, findings: dict[str, float]) -> list[str]:
    """Problems with the numbers ``text`` cites (empty when every one is backed by ``findings``)."""
    problems = []
    body = re.sub(r"`[^`]*`", "", text)  # code spans (commands, commit ids) are not findings
    cited = [(m, True) for m in NUMBER.finditer(body)] + [(m, False) for m in WHOLE.finditer(body)]
    for m, decimal in sorted(cited, key=lambda c: c[0].start()):
        shown, key = m.group(1).replace("−", "-").replace("×", "").replace(",", ""), m.group(2)
        if key is None:
            problems.append(f"{shown}: no key says which generated number it is")
            continue
        name, _, mod = key.partition("|")
        if name not in findings:
            problems.append(f"{shown}: unknown key {name}")
            continue
        value = abs(findings[name]) if mod == "abs" else findings[name]
        decimals = len(shown.split(".")[1]) if decimal else 0
        if round(value, decimals) != round(float(shown), decimals) and f"{value:.{decimals}f}" != shown.lstrip("+"):
            problems.append(f"{shown}: {name} is {value:.{decimals + 2}f}")
            continue
        if name.endswith(SIGNED) and mod != "abs":
            centre = findings.get(name.rsplit(".", 1)[0] + ".centre", 0.0)
            sign = 0 if value == centre else (1 if value > centre else -1)
            said = _stated_direction(_sentence_before(body, m.start()))
            if said and sign and said != sign:
                problems.append(f"{m.group(1)}: the sentence says {'up' if said > 0 else 'down'}, but {name} is"
                                f" {value:.4g}{' (a ratio: against 1)' if centre else ''}")
    return problems
