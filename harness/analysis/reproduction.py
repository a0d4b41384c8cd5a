"""Did these runs reproduce a committed report? Run by run: did the training, and if not, why.

``compare(ours, reference)`` matches the per-run frame of a study (``report.results``) with a
committed ``runs.csv`` on (variant, scene, seed) and compares every deterministic metric both
sides recorded (the metric registry: timings are not; a registry ``difference`` is left out,
its two metrics are compared) and, where both sides recorded it, the digest of the trained
model (``model_digest``, ``run.training``). A metric's registry ``source`` says which side of
a run it measures: ``trainer`` metrics (``train_psnr``, ``l1``, ``n_gaussians``, ...) the
training, ``evaluation`` and ``diagnostics`` metrics what was computed from the trained model.
Each pair gets one ``class``:

- ``identical``: every compared number equal, and the model bits where both recorded them;
- ``evaluation differs``: the training is identical (every training number and the model
  bits), but an evaluation or diagnostics metric differs: only the code or the environment
  that scores a model moved;
- ``expected to differ``: the training differs, and the two runs are not the same run: another
  determinism domain (``domain``: a default-mode run on another CPU, or another kernel set,
  thread count or package versions; ``ftgspp/runtime/determinism.py``) or another config
  (``config_hash``);
- ``differs unexpectedly``: the training differs in the same domain with the same config, be
  it another trainer code (``trainer_fingerprint``: the reference is stale) or unexplained,
  which is a finding worth an issue;
- ``not compared``: a side did not finish, or nothing training-side was recorded on both.

The training counts as identical ("training identical (bit for bit)") in the first two
classes. A metric recorded on one side only differs (``inf`` in its ``diff.`` column). A
reference without ``model_digest`` (reports made before it existed) is compared on its
numbers alone, and ``model_bits`` says "not recorded in the reference".

``summary(frame, reference)`` is the verdict ``make demo`` ends with; ``strict_failure(frame)``
is what fails ``study check --strict``.
"""

from __future__ import annotations

import math

import pandas as pd

from harness.analysis.aggregate import metric_columns
from harness.spec.metrics import DIAGNOSTICS, EVALUATION, TRAINER, lookup

KEY = ["variant", "scene", "seed"]
DIGEST = "model_digest"
IDENTICAL, EVALUATION_DIFFERS = "identical", "evaluation differs"
EXPECTED, UNEXPECTED, NOT_COMPARED = "expected to differ", "differs unexpectedly", "not compared"
CLASSES = (IDENTICAL, EVALUATION_DIFFERS, EXPECTED, UNEXPECTED, NOT_COMPARED)
# provenance columns, read as text (a hex id of digits alone must not become a number)
TEXT_COLUMNS = ("config_hash", "trainer_fingerprint", "domain", "determinism", "cpu_capability", "cpu_model",
                "torch_threads", DIGEST, "git_sha", "start_time")
ANOTHER_DOMAIN, ANOTHER_CONFIG, TRAINER_CODE = "another determinism domain", "another config", "trainer code"


def answered(runs: pd.DataFrame) -> pd.Series:
    """Which rows of a runs frame are a trainer's answer: finished, or diverged (a recorded
    divergence is that code's result); a crash or an interruption is not."""
    failure = runs["failure"] if "failure" in runs else pd.Series("", index=runs.index)
    return (runs.status == "FINISHED") | ((runs.status == "FAILED") & (failure == "diverged"))


def read_reference(path: str) -> pd.DataFrame:
    """A committed ``runs.csv`` with floats read back exactly as written (pandas' default parser is
    exact for what ``to_csv`` writes: every float of the committed reports reads back bit for bit;
    ``float_precision="round_trip"`` is deprecated)."""
    return pd.read_csv(path, keep_default_na=False, na_values=[""],
                       dtype={c: str for c in TEXT_COLUMNS})


def side(metric: str) -> str:
    """Which side of a run a metric measures: ``training``, ``evaluation`` or "" (not compared)."""
    m = lookup(metric)
    if not m.deterministic or m.source not in (TRAINER, EVALUATION, DIAGNOSTICS):
        return ""
    return "training" if m.source == TRAINER else "evaluation"


def _text(row: pd.Series, col: str) -> str:
    value = row.get(col, "")
    if value is None or (not isinstance(value, str) and pd.isna(value)):
        return ""
    if isinstance(value, float) and value.is_integer():  # a thread count read back as 1.0
        return str(int(value))
    return str(value).strip()


def _number(value: object) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def _differences(a: pd.Series, b: pd.Series, metrics: list[str]) -> tuple[dict[str, float], list[str], int]:
    """Per differing metric its absolute difference (``inf``: recorded on one side only), the
    same as text, and how many metrics were compared (recorded on at least one side)."""
    diffs: dict[str, float] = {}
    text: list[str] = []
    compared = 0
    for m in metrics:
        x, y = _number(a.get(m)), _number(b.get(m))
        if math.isnan(x) and math.isnan(y):
            continue
        compared += 1
        if math.isnan(x) or math.isnan(y):
            diffs[m] = math.inf
            text.append(f"{m} (only {'in the reference' if math.isnan(x) else 'here'})")
        elif x != y:
            diffs[m] = abs(x - y)
            text.append(f"{m} {diffs[m]:.2g}")
    return diffs, text, compared


def _model_bits(a: pd.Series, b: pd.Series) -> str:
    x, y = _text(a, DIGEST), _text(b, DIGEST)
    if x and y:
        return "equal" if x == y else "differ"
    if not x and not y:
        return "not recorded"
    return "not recorded in the reference" if x else "not recorded here"


def _domain(a: pd.Series, b: pd.Series) -> str:
    """How two runs' determinism domains differ ("" when they do not, or one is unrecorded)."""
    x, y = _text(a, "domain"), _text(b, "domain")
    if not x or not y or x == y:
        return ""
    mode_x, mode_y = _text(a, "determinism"), _text(b, "determinism")
    parts = []
    if mode_x != mode_y:
        parts.append(f"{mode_y or '?'} mode in the reference, {mode_x or '?'} here")
    elif mode_x != "portable":
        parts.append(f"non-portable ({mode_x or 'default'} mode)")
    found = mode_x != mode_y
    for col, what in (("cpu_model", "CPU"), ("cpu_capability", "torch kernels"), ("torch_threads", "torch threads")):
        u, v = _text(a, col), _text(b, col)
        if u != v and not (col == "cpu_model" and mode_x == mode_y == "portable"):  # not part of a portable domain
            parts.append(f"{what} {v or '?'} in the reference, {u or '?'} here")
            found = True
    if not found:
        parts.append("package versions or another setting")
    return f"{ANOTHER_DOMAIN} ({y} in the reference, {x} here: {', '.join(parts)})"


def _provenance(a: pd.Series, b: pd.Series) -> list[tuple[str, str]]:
    """(short reason, detail) for each recorded difference of two runs' provenance, those that
    make them different runs (domain, config) first."""
    out = []
    if domain := _domain(a, b):
        out.append((ANOTHER_DOMAIN, domain))
    x, y = _text(a, "config_hash"), _text(b, "config_hash")
    if x and y and x != y:
        out.append((ANOTHER_CONFIG, f"{ANOTHER_CONFIG} ({y} in the reference, {x} here)"))
    for col, what in (("trainer_fingerprint", TRAINER_CODE), ("domain", "determinism domain")):
        x, y = _text(a, col), _text(b, col)
        if not x or not y:
            missing = f"{what} not recorded {'here' if not x else 'in the reference'}"
            out.append((missing, missing))
        elif x != y and col == "trainer_fingerprint":
            out.append((TRAINER_CODE, f"{TRAINER_CODE} ({y} in the reference, {x} here)"))
    return out


def _classify(a: pd.Series, b: pd.Series, training: list[str], evaluation: list[str]) -> dict[str, object]:
    t_diffs, t_text, t_n = _differences(a, b, training)
    e_diffs, e_text, e_n = _differences(a, b, evaluation)
    bits = _model_bits(a, b)
    t_text += ["model bits"] if bits == "differ" else []
    psnr = _number(a.get("psnr")) - _number(b.get("psnr")) if "psnr" in evaluation else math.nan
    row: dict[str, object] = dict(training_compared=t_n, evaluation_compared=e_n, model_bits=bits, psnr_diff=psnr,
                                  training_differing=", ".join(t_text), evaluation_differing=", ".join(e_text),
                                  **{f"diff.{m}": d for m, d in {**t_diffs, **e_diffs}.items()})
    if t_n == 0 and bits not in ("equal", "differ"):
        why = "no training metric or model digest recorded on both sides"
        return {**row, "class": NOT_COMPARED, "reason": why, "why": why}
    reasons = _provenance(a, b)
    if not t_diffs and bits != "differ":
        if not e_diffs:
            return {**row, "class": IDENTICAL, "reason": "", "why": ""}
        cls = EVALUATION_DIFFERS
    else:
        cls = EXPECTED if reasons and reasons[0][0] in (ANOTHER_DOMAIN, ANOTHER_CONFIG) else UNEXPECTED
    unexplained = ("unexplained", "unexplained: same config, code and determinism domain")
    reasons = reasons or [unexplained]
    short = [r for r, _ in reasons if cls != EXPECTED or r in (ANOTHER_DOMAIN, ANOTHER_CONFIG)]
    return {**row, "class": cls, "reason": ", ".join(short), "why": "; ".join(d for _, d in reasons)}


def compare(ours: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """One row per (variant, scene, seed) of either side: ``class``, ``reason`` (short) and
    ``why`` (detail), ``model_bits``, the differing training and evaluation metrics (text, and
    the absolute difference of each in a ``diff.METRIC`` column), how many of each were
    compared, and ``psnr_diff`` (here minus the reference)."""
    common = set(metric_columns(ours)) & set(metric_columns(reference))
    common -= {DIGEST}
    training = sorted(m for m in common if side(m) == "training")
    evaluation = sorted(m for m in common if side(m) == "evaluation")
    ref = reference.assign(seed=reference.seed.astype(int)).set_index(KEY)
    mine = ours.assign(seed=ours.seed.astype(int)).set_index(KEY)
    rows = []
    for key in list(dict.fromkeys([*mine.index, *ref.index])):
        a = mine.loc[key] if key in mine.index else None
        b = ref.loc[key] if key in ref.index else None
        row: dict[str, object] = dict(zip(KEY, key))
        if a is None or b is None or a.status != "FINISHED" or b.status != "FINISHED":
            why = ("not run here" if a is None else "not in the reference" if b is None
                   else f"not finished {'here' if a.status != 'FINISHED' else 'in the reference'}")
            row.update({"class": NOT_COMPARED, "reason": why, "why": why})
        else:
            row.update(_classify(a, b, training, evaluation))
        rows.append(row)
    columns = [*KEY, "class", "reason", "model_bits", "training_differing", "evaluation_differing",
               "training_compared", "evaluation_compared", "psnr_diff", "why"]
    frame = pd.DataFrame(rows)
    frame = frame.reindex(columns=[*columns, *sorted(c for c in frame.columns if c not in columns)])
    return frame


def _counted(values: pd.Series) -> str:
    """``another determinism domain`` (one reason) or ``8 another determinism domain, 2 ...``."""
    counts = values.value_counts()
    if len(counts) == 1:
        return str(counts.index[0])
    return ", ".join(f"{n} {r}" for r, n in counts.items())


def _largest(rows: pd.DataFrame) -> str:
    """``lpips_alex by ≤ 1.4e-09, ...``: the largest difference of each evaluation metric."""
    out = []
    for col in sorted(c for c in rows.columns if c.startswith("diff.")):
        d = rows[col].dropna()
        if len(d):
            name = col.removeprefix("diff.")
            out.append(f"{name} recorded on one side only" if math.isinf(d.max()) else f"{name} by ≤ {d.max():.2g}")
    return ", ".join(out)


def summary(frame: pd.DataFrame, reference: str) -> list[str]:
    """The verdict: ``25 runs compared with the committed report (...): 15 training identical
    (bit for bit), of which ...; 10 expected to differ (...); 0 differ unexpectedly``, then
    one line per reason with the runs' largest PSNR difference."""
    cls = frame["class"]
    compared = frame[cls != NOT_COMPARED]
    n = {c: int((cls == c).sum()) for c in CLASSES}
    same = n[IDENTICAL] + n[EVALUATION_DIFFERS]
    head = f"{len(compared)} run{'s' if len(compared) != 1 else ''} compared with the committed report ({reference})"
    head += f": {same} training identical (bit for bit)"
    if same:
        evaluation = frame[cls == EVALUATION_DIFFERS]
        head += f", of which {n[IDENTICAL]} in every metric and {n[EVALUATION_DIFFERS]} differ only in evaluation"
        head += f" ({_largest(evaluation)})" if len(evaluation) else ""
    head += f"; {n[EXPECTED]} expected to differ"
    head += f" ({_counted(frame[cls == EXPECTED].reason)})" if n[EXPECTED] else ""
    head += f"; {n[UNEXPECTED]} differ{'s' if n[UNEXPECTED] == 1 else ''} unexpectedly"
    head += f" ({_counted(frame[cls == UNEXPECTED].reason)})" if n[UNEXPECTED] else ""
    lines = [head]
    trained = frame[cls.isin([IDENTICAL, EVALUATION_DIFFERS])]
    for bits, k in trained.model_bits.value_counts().items():
        lines.append(f"  training identical: model bits {bits} ({k} run{'s' if k != 1 else ''})")
    for c, what in ((EVALUATION_DIFFERS, "differ only in evaluation"), (EXPECTED, "expected to differ"),
                    (UNEXPECTED, "differ unexpectedly")):
        rows = frame[cls == c]
        for why, k in rows.why.value_counts().items():
            psnr = rows[rows.why == why].psnr_diff.dropna().abs()
            size = f"; PSNR by up to {psnr.max():.4f} dB" if c != EVALUATION_DIFFERS and len(psnr) else ""
            lines.append(f"  {k} {what}: {why}{size}")
    skipped = frame[cls == NOT_COMPARED]
    if len(skipped):
        lines.append(f"{len(skipped)} not compared: " + "; ".join(
            f"{k} {why}" for why, k in skipped.why.value_counts().items()))
    return lines


def hosts(runs: pd.DataFrame) -> str:
    """The CPUs (and torch kernel sets) runs were made on, most runs first: ``AMD EPYC with torch kernels AVX512 (25
    runs)`` — the committed report's host as its runs.csv records it (``cpu_model``, ``cpu_capability``)."""
    if runs.empty or "cpu_model" not in runs:
        return "an unrecorded host"
    kinds = runs.fillna({"cpu_model": "?", "cpu_capability": "?"}).groupby(
        ["cpu_model", "cpu_capability"]).size().sort_values(ascending=False)
    return "; ".join(f"{cpu} with torch kernels {cap} ({k} run{'s' if k != 1 else ''})" for (cpu, cap), k in kinds.items())


def strict_failure(frame: pd.DataFrame) -> bool:
    """Whether ``study check --strict`` fails: a run differs unexpectedly, or none was compared."""
    cls = frame["class"]
    return bool((cls == UNEXPECTED).any() or not (cls != NOT_COMPARED).any())
