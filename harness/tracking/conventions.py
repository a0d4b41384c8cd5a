"""MLflow's own conventions for a run, so its UI shows what users expect.

- ``source_tags``: ``mlflow.source.name`` (the ``study run`` command), ``mlflow.source.type``
  (``JOB`` under SLURM, else ``LOCAL``), ``mlflow.source.git.commit`` and ``mlflow.user``;
  the UI's Source and Version columns come from them.
- ``scene_dataset``: the run's scene as an MLflow dataset input (name, digest = a fingerprint
  of the scene, source = the synthetic generator's arguments or the data folder, profile =
  format and path), so runs can be grouped by dataset.
- ``run_name``: a child run's name, ``<variant>/<scene>/seed<k> [<profile>]``, so runs of one
  study made under two profiles never share a name (their ``profile`` tag says it too);
- ``ui_link``: where the MLflow UI shows an experiment's training runs, as the study's view
  (``study_view``: the runs grouped by profile and variant, with the profile, variant, scene
  and seed columns first, then PSNR, SSIM, LPIPS and training time), after the command that
  serves a SQLite store (``mlflow_executable``: the ``mlflow`` beside the running interpreter,
  so it works without activating the environment); ``run_link`` one run, in the training view;
  ``browse_command`` the shell command a report gives for opening the store;
- ``experiment_tags``: the experiment's description (``mlflow.note.content``: the study's
  question and the commands that fill and report it, in plain text) and that view;
- ``system_metrics``: MLflow's own ``SystemMetricsMonitor`` (``system/cpu_utilization_percentage``,
  ``system/system_memory_usage_megabytes``, ...) sampling every 15 s; a no-op when psutil
  is missing;
- ``verdict_tags``: the tags ``study report`` sets on the parent run it reports, one
  ``verdict.<claim>`` per claim (``report.mlflow_answer``).
"""

from __future__ import annotations

import contextlib
import getpass
import hashlib
import json
import logging
import os
import re
import shlex
import shutil
import sys
from pathlib import Path
from typing import Any, Iterator

from harness.tracking.provenance import git_sha
from harness.tracking.store import display_uri

SYSTEM_METRICS_INTERVAL_S = 15.0
SYNTH_GENERATOR = "ftgspp.data.synthetic.build.generate"
PROFILE_TAG = "profile"  # every child and parent run's study profile (quick, smoke, paper)
VERDICT_TAG_PREFIX = "verdict."  # verdict.<claim> = reproduced | inconclusive | ... on a reported parent run


def run_name(label: str, profile: str) -> str:
    """A child run's name: its label (``baseline/studio/seed0``) and its profile in brackets.

    The profile is part of the name because the same (variant, scene, seed) runs under every
    profile of a study, and MLflow's tables show names, not keys.
    """
    return f"{label} [{profile}]"


def verdict_tags(verdicts: dict[str, str]) -> dict[str, str]:
    """``{claim: verdict}`` as the parent run's tags ``verdict.<claim>``; one scene of a
    scene-dependent claim (``claim[scene]``) as ``verdict.<claim>/<scene>`` (MLflow's keys allow
    letters, digits and ``_-. :/`` only; anything else becomes ``_``)."""
    def key(claim: str) -> str:
        claim = re.sub(r"\[([^\]]*)\]", r"/\1", claim)
        return VERDICT_TAG_PREFIX + re.sub(r"[^\w.\- :/]", "_", claim)

    return {key(claim): verdict for claim, verdict in verdicts.items()}


def source_tags(command: str) -> dict[str, str]:
    """Standard ``mlflow.source.*`` / ``mlflow.user`` tags of a run started by ``command``."""
    sha = git_sha()
    tags = {
        "mlflow.source.name": command,
        "mlflow.source.type": "JOB" if os.environ.get("SLURM_JOB_ID") else "LOCAL",
    }
    if sha != "unknown":
        tags["mlflow.source.git.commit"] = sha.removesuffix("-dirty")
    with contextlib.suppress(Exception):  # no user name in some containers
        tags["mlflow.user"] = getpass.getuser()
    return tags


def folder_fingerprint(path: Path) -> str:
    """16 hex digits from the relative names and sizes of every file under ``path``."""
    h = hashlib.sha256()
    if path.is_dir():
        for root, dirs, files in os.walk(path):
            dirs.sort()
            for name in sorted(files):
                f = Path(root) / name
                h.update(f"{f.relative_to(path).as_posix()}\0{f.stat().st_size}\n".encode())
    return h.hexdigest()[:16]


def scene_dataset(name: str, data_path: str, data_format: str, synth: dict[str, Any] | None) -> Any:
    """A ``DatasetInput`` for the run's scene (``mlflow.data.context=train``).

    A synthetic scene is identified by its generator arguments (the generator is
    deterministic), a real one by its files' names and sizes.
    """
    from mlflow.entities import Dataset, DatasetInput, InputTag

    if synth is not None:
        args = json.dumps(synth, sort_keys=True)
        digest = hashlib.sha256(args.encode()).hexdigest()[:16]
        source_type, source = "synthetic", json.dumps({"generator": SYNTH_GENERATOR, "args": synth}, sort_keys=True)
        fmt = str(synth.get("layout", data_format))
    else:
        digest = folder_fingerprint(Path(data_path))
        source_type, source = "local", json.dumps({"uri": str(Path(data_path).resolve())})
        fmt = data_format
    profile = json.dumps({"format": fmt, "path": data_path})
    dataset = Dataset(name=name, digest=digest, source_type=source_type, source=source, profile=profile)
    return DatasetInput(dataset=dataset, tags=[InputTag(key="mlflow.data.context", value="train")])


@contextlib.contextmanager
def system_metrics(run_id: str, tracking_uri: str) -> Iterator[None]:
    """Sample CPU, memory, disk and network into the run while the block runs."""
    monitor = None
    try:
        import psutil  # noqa: F401  MLflow's CPU monitor needs it
        from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

        logging.getLogger("mlflow.system_metrics").setLevel(logging.WARNING)
        monitor = SystemMetricsMonitor(run_id, sampling_interval=SYSTEM_METRICS_INTERVAL_S,
                                       tracking_uri=tracking_uri)
        monitor.start()
    except Exception:  # psutil missing or the monitor cannot start: training goes on without it
        monitor = None
    try:
        yield
    finally:
        if monitor is not None:
            monitor.finish()


# The MLflow UI (3.x) restores an experiment page's filter, order, columns and grouping from an
# experiment tag ``mlflow.sharedViewState.<key>`` (JSON) when the URL carries
# ``viewStateShareKey=<key>``: how its "Share" button works. The study sets one such view. The
# URL itself can carry only the filter and order (``searchFilter``, ``orderByKey``, ...), and
# with any of them the UI ignores the shared view; columns and grouping exist only in the view.
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
VIEW_KEY = "ftgspp-study"
NOTE_TAG = "mlflow.note.content"  # the description: markdown on the experiment page, raw text in the lists
TRAINING_VIEW = "workflowType=machine_learning"  # the training-runs view, not the GenAI one
# the view's metric columns: registry names (tracking imports no other wing, so a test checks
# each against harness/spec/metrics.py)
VIEW_METRICS = ("psnr", "ssim1", "lpips_alex", "lpips_alex_01", "train_seconds")
# the study's key tags, the view's first columns, with their widths in pixels ("dispatch_baseline" fits)
VIEW_TAGS = {PROFILE_TAG: 70, "variant": 150, "scene": 90, "seed": 60}
# the groups: one per (profile, variant), so a group's mean never mixes a smoke run with a quick one
VIEW_GROUP_TAGS = (PROFILE_TAG, "variant")
# the run-name column, wide enough for "Group: profile: quick, variant: dispatch_avx2" and for
# "dispatch_baseline/studio/seed0 [quick]"; the metric columns wide enough for "31.556 (average)"
VIEW_NAME_COLUMN, VIEW_NAME_PX, VIEW_METRIC_PX = "attributes.`Run Name`", 330, 120
VIEW_FILTER_TAG = "variant"  # carried by every child run, by no parent run


def _column(kind: str, name: str) -> str:
    return f"{kind}.`{name}`"  # the UI's canonical column key, also its table's column id


def study_view(metrics: tuple[str, ...] = VIEW_METRICS) -> dict[str, Any]:
    """The view state ``ui_link`` opens: the training runs (the filter leaves out the
    invocations' parent runs, which carry no ``variant`` tag) grouped by profile and variant
    (each group's row shows its runs' mean: quick and smoke runs are never averaged together),
    in the order they started (a study's variants in its file's order), with the study's key
    tags as the first columns and then the headline metrics. A run without a ``profile`` tag
    would land in the UI's "Additional runs" group; every run the harness made carries one.

    ``selectedColumns`` says which columns show, ``columnOrder`` where (the UI would otherwise
    put every metric before every tag), ``columnWidths`` how wide (pixels: the UI sizes only
    the columns ``columnOrder`` names, hence the run name there); ``groupBy`` is the UI's
    ``RunsGroupByConfig``. The UI shows a metric as JavaScript prints the number (a
    group's mean to 9 or more digits): MLflow 3.17 has no per-column format, so the means at
    the registry's decimals are on the reported parent run (``report.mlflow_answer``).
    """
    columns = [*(_column("tags", t) for t in VIEW_TAGS), *(_column("metrics", m) for m in metrics)]
    return {
        "searchFilter": f"tags.{VIEW_FILTER_TAG} LIKE '%'",
        "orderByKey": _column("attributes", "start_time"),
        "orderByAsc": True,
        "selectedColumns": columns,
        "columnOrder": [VIEW_NAME_COLUMN, *columns],
        "columnWidths": {VIEW_NAME_COLUMN: VIEW_NAME_PX, **{_column("tags", t): px for t, px in VIEW_TAGS.items()},
                         **{_column("metrics", m): VIEW_METRIC_PX for m in metrics}},
        "groupBy": {"aggregateFunction": "average",
                    "groupByKeys": [{"mode": "tag", "groupByData": t} for t in VIEW_GROUP_TAGS]},
    }


def experiment_note(question: str, command: str, report: str) -> str:
    """The experiment's description: plain text with no markdown syntax, because the
    experiment page renders it as markdown while the home page's and the experiments list's
    Description column show it verbatim (one line, whitespace collapsed)."""
    return (f"{' '.join(question.split())}\n\nRuns: {command} \N{EM DASH} report (tables, plots, verdicts):"
            f" {report} \N{EM DASH} one run per (variant, scene, seed).")


def experiment_tags(question: str, command: str, report: str) -> dict[str, str]:
    """The tags that describe a study's experiment in the UI: its description (question, the
    command that fills it, the command that reports it) and the study view ``ui_link`` opens."""
    return {NOTE_TAG: experiment_note(question, command, report),
            VIEW_TAG_PREFIX + VIEW_KEY: json.dumps(study_view())}


def _ui_base(uri: str) -> str:
    if uri.startswith(("http://", "https://")):
        return uri.rstrip("/") + "/"
    return "http://127.0.0.1:5000/"


def mlflow_executable() -> str:
    """The ``mlflow`` command of the environment the harness runs in, as an absolute path: the
    console script beside the running interpreter (``.venv/bin/mlflow``), so the printed command
    works without activating the environment; else the one on PATH; else plain ``mlflow``."""
    beside = Path(sys.executable).parent / "mlflow"  # not resolved: a venv's python is a symlink
    if beside.is_file() and os.access(beside, os.X_OK):
        return str(beside.absolute())
    found = shutil.which("mlflow")
    return os.path.abspath(found) if found else "mlflow"


def _relative_to_cwd(path: str) -> str:
    """``path`` relative to the working directory when inside it (``.venv/bin/mlflow``: what a
    report committed from one clone can say to every other), else as given."""
    try:
        return Path(path).relative_to(Path.cwd()).as_posix()
    except ValueError:
        return path


def _ui_command(uri: str, executable: str) -> str:
    """The shell command serving a SQLite store on http://127.0.0.1:5000, quoted for the shell."""
    return shlex.join([executable, "ui", "--backend-store-uri", uri])


def _ui_hint(uri: str, url: str) -> str:
    if uri.startswith(("http://", "https://")):
        return url
    return f"{_ui_command(uri, mlflow_executable())}, then {url}"


def ui_link(uri: str, experiment_id: str) -> str:
    """Where the experiment's runs table is in the MLflow UI, in the study view, after the
    command that serves a SQLite store (the environment's ``mlflow`` by its absolute path).

    MLflow 3.17's UI opens every experiment in the GenAI view unless the browser chose
    "Model training" before (it ignores ``mlflow.experimentKind`` there); the
    ``workflowType`` parameter selects the training-runs view, ``viewStateShareKey`` the
    filter, columns and grouping of ``study_view`` (the link must carry no filter or order of
    its own, or the UI ignores the view).
    """
    page = f"#/experiments/{experiment_id}/runs?{TRAINING_VIEW}&viewStateShareKey={VIEW_KEY}"
    return _ui_hint(uri, _ui_base(uri) + page)


def browse_command(uri: str) -> str:
    """The shell command that shows the store's runs, as a report page gives it: ``mlflow ui`` on
    a SQLite store (the environment's ``mlflow`` and the store both as ``display_uri`` writes
    paths: relative to the working directory, the clone's root, when inside it), else ``open`` on
    the URI."""
    if not uri.startswith("sqlite"):
        return f"open {uri}"
    return _ui_command(display_uri(uri), _relative_to_cwd(mlflow_executable()))


def run_link(uri: str, experiment_id: str, run_id: str) -> str:
    """One run's page (overview, metrics, artifacts) in the training-runs view.

    MLflow 3.17 draws a run page as a training run or as a GenAI evaluation from the
    ``workflowType`` in its URL, else from the browser's saved choice (the sidebar's switch,
    GenAI until a user flips it), never from the experiment's ``mlflow.experimentKind``; the
    run-name links of its runs table carry no ``workflowType``. This link carries it.
    """
    return _ui_hint(uri, f"{_ui_base(uri)}#/experiments/{experiment_id}/runs/{run_id}?{TRAINING_VIEW}")
