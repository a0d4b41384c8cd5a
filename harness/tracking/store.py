"""The tracking store: one explicit ``MlflowClient`` with the locking SQLite needs.

``Store`` wraps one ``MlflowClient(tracking_uri)`` (never mlflow's global state). With
the default embedded SQLite store (``sqlite:///mlflow.db``) several processes of one
study write to the same file, so every write takes an inter-process lock
(``<db>.lock``, ``fcntl.flock``) and is retried if SQLite still reports "database is
locked" (another program, e.g. ``mlflow ui``, holding it). With an ``http(s)://``
``mlflow server`` URI the client logs over HTTP and the server serialises.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Callable, Iterator, TypeVar

from ftgspp.errors import InputError

DEFAULT_URI = "sqlite:///mlflow.db"
PARAMS_PER_BATCH = 100  # MLflow's limit for params/tags per log_batch
METRICS_PER_BATCH = 900  # below MLflow's 1000 entities per log_batch
TAG_MAX_CHARS = 4_000
EXPERIMENT_KIND = "mlflow.experimentKind"  # the UI's choice between GenAI traces and training runs
TRAINING_KIND = "custom_model_development"
DB_SCHEMES = ("postgresql", "mysql", "mssql")  # SQLAlchemy stores other than SQLite
T = TypeVar("T")


def resolve_uri(explicit: str | None, configured: str) -> str:
    """``tracking.uri=`` given on the command line, else ``MLFLOW_TRACKING_URI`` (an empty one is
    unset), else the config; ``InputError`` (one line) for a URI that is not one (``check_uri``).

    A relative SQLite path is made absolute (MLflow caches stores by URI, and worker
    processes must find the same file).
    """
    if explicit is not None:
        uri, where = explicit, "tracking.uri"
    elif os.environ.get("MLFLOW_TRACKING_URI"):
        uri, where = os.environ["MLFLOW_TRACKING_URI"], "MLFLOW_TRACKING_URI"
    else:
        uri, where = configured or DEFAULT_URI, "tracking.uri"
    check_uri(uri, where)
    path = sqlite_path(uri)
    return f"sqlite:///{path.resolve()}" if path is not None and not path.is_absolute() else uri


URI_FORMS = "sqlite:///PATH.db, http(s)://HOST:PORT or postgresql://USER@HOST/DB"


def check_uri(uri: str, where: str = "tracking.uri") -> None:
    """``InputError`` naming ``where`` unless ``uri`` is a well-formed tracking URI of a store
    this harness uses: ``sqlite:///`` and a file path (relative, or absolute after a fourth slash)
    that is not a folder, ``http(s)://`` and a host (a port is a number), or a database URL
    (postgresql, mysql, mssql, with an optional ``+driver``) SQLAlchemy can parse. Nothing is
    connected to here (``check_store`` does that)."""
    import re
    import urllib.parse

    def bad(problem: str) -> InputError:
        return InputError(where, f"'{_redact(uri)}' {problem} (a tracking URI is {URI_FORMS})")

    if not uri.strip():
        raise bad("is empty")
    match = re.match(r"([A-Za-z][A-Za-z0-9+.-]*):", uri)
    if match is None or len(match.group(1)) == 1:  # c:\path: a drive letter, not a scheme
        raise bad("has no scheme: a local store is sqlite:///PATH.db")
    scheme = match.group(1).lower()
    base = scheme.split("+", 1)[0]
    if base == "sqlite":
        path = sqlite_path(uri)
        if path is not None and not uri[len("sqlite:///"):]:
            raise bad("names no database file: sqlite:///PATH.db")
        if path is None:
            raise bad("is not a SQLite URI: sqlite:/// (three slashes) and a file, sqlite:////abs/path.db for an"
                      " absolute path")
        if path.is_dir():
            raise bad(f"names the folder {path}, not a database file")
        return
    if scheme in ("http", "https"):
        parts = urllib.parse.urlsplit(uri)
        try:
            parts.port  # noqa: B018 - raises for a port that is not a number
        except ValueError as exc:
            raise bad(f"has a bad port ({exc})") from None
        if not uri.lower().startswith(f"{scheme}://") or not parts.hostname:
            raise bad(f"names no host: {scheme}://HOST:PORT")
        return
    if base in DB_SCHEMES:
        from sqlalchemy.engine import make_url

        try:
            url = make_url(uri)
        except Exception as exc:  # ArgumentError, ValueError: not a URL SQLAlchemy can read
            raise bad(f"is not a database URL ({str(exc).splitlines()[0]})") from None
        if not url.host and not url.database:
            raise bad(f"names no host or database: {base}://USER@HOST/DB")
        return
    raise bad(f"has the scheme '{scheme}', which this harness does not use")


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (relative to the working directory), else None."""
    return Path(uri[len("sqlite:///") :]) if uri.startswith("sqlite:///") else None


def display_uri(uri: str) -> str:
    """A SQLite URI inside the working directory as the relative ``sqlite:///mlflow.db`` a reader
    can reuse; any other URI as given."""
    path = sqlite_path(uri)
    if path is None:
        return uri
    try:
        return "sqlite:///" + path.relative_to(Path.cwd()).as_posix()
    except ValueError:
        return uri


def store_exists(uri: str) -> bool:
    """False only for a SQLite store whose file does not exist yet (reading must not create it)."""
    path = sqlite_path(uri)
    return path is None or path.is_file()


def check_store(uri: str, timeout_s: float = 5.0) -> None:
    """Fail with one clear line if the store cannot be used, before anything is written."""
    check_uri(uri)
    path = sqlite_path(uri)
    if path is not None:
        folder = path.resolve().parent
        if not folder.is_dir() or not os.access(folder, os.W_OK):
            raise InputError("tracking.uri", f"{uri}: folder {folder} does not exist or is not writable")
        return
    check_reachable(uri, timeout_s)


def check_reachable(uri: str, timeout_s: float = 5.0) -> None:
    """One line (``InputError``) if the server or database of a non-SQLite ``uri`` does not
    answer within ``timeout_s`` (MLflow's own client would retry for minutes); reads nothing."""
    if uri.split(":", 1)[0].split("+", 1)[0] in DB_SCHEMES:
        _check_database(uri, timeout_s)
        return
    if uri.startswith(("http://", "https://")):
        try:
            with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=timeout_s) as resp:
                if resp.status != 200:
                    raise InputError("tracking.uri", f"{uri}: /health answered HTTP {resp.status}")
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            raise InputError("tracking.uri", f"cannot reach an MLflow server at {uri} ({reason})") from None


def _check_database(uri: str, timeout_s: float) -> None:
    """Connect once to a database store (e.g. ``postgresql+psycopg://``); InputError if refused."""
    try:
        import sqlalchemy

        engine = sqlalchemy.create_engine(uri, connect_args={"connect_timeout": int(max(1, timeout_s))})
        try:
            with engine.connect():
                pass
        finally:
            engine.dispose()
    except ImportError as exc:
        raise InputError("tracking.uri", f"{_redact(uri)}: driver missing ({exc}); pip install 'psycopg[binary]'") \
            from None
    except Exception as exc:  # OperationalError: refused, bad password, no such database
        reason = str(getattr(exc, "orig", exc) or exc).strip().splitlines()[0]
        raise InputError("tracking.uri", f"database refused the connection at {_redact(uri)} ({reason})") from None


def _redact(uri: str) -> str:
    """The URI with any password replaced by ``***``."""
    scheme, sep, rest = uri.partition("://")
    creds, at, host = rest.rpartition("@")
    if not at or ":" not in creds:
        return uri
    return f"{scheme}{sep}{creds.split(':', 1)[0]}:***@{host}"


def _is_locked(exc: BaseException) -> bool:
    text = str(exc).lower()
    return "database is locked" in text or "database table is locked" in text


class Store:
    """One tracking store: a client plus the write lock and retry that SQLite needs."""

    def __init__(self, uri: str, retry_s: float = 120.0) -> None:
        from mlflow.tracking import MlflowClient

        logging.getLogger("alembic").setLevel(logging.WARNING)
        logging.getLogger("mlflow.store.db.utils").setLevel(logging.WARNING)  # "Creating initial ... tables"
        check_uri(uri)  # one line for a malformed URI, not SQLAlchemy's traceback
        self.uri = uri
        self.retry_s = retry_s
        db = sqlite_path(uri)
        self._lock_path = db.with_name(db.name + ".lock") if db is not None else None
        if db is not None and not db.is_file():  # creating it runs migrations: one process at a time
            with self._locked():
                self.client = MlflowClient(tracking_uri=uri)
                self.client.search_experiments(max_results=1)
        else:
            self.client = MlflowClient(tracking_uri=uri)

    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        if self._lock_path is None:
            yield
            return
        with open(self._lock_path, "a") as fh:
            fcntl.flock(fh, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)

    def call(self, fn: Callable[..., T], *args: Any, write: bool = True, **kwargs: Any) -> T:
        """``fn(*args, **kwargs)`` under the write lock, retried while SQLite is locked."""
        deadline = time.monotonic() + self.retry_s
        delay = 0.05
        while True:
            try:
                if write:
                    with self._locked():
                        return fn(*args, **kwargs)
                return fn(*args, **kwargs)
            except Exception as exc:
                if not _is_locked(exc) or time.monotonic() > deadline:
                    raise
                time.sleep(delay)
                delay = min(delay * 2, 2.0)

    # --- experiments and runs -------------------------------------------------------

    def experiment_id(self, name: str, create: bool = True) -> str | None:
        """Id of the experiment ``name``; created if missing and ``create``.

        A created experiment is tagged as a training experiment (``mlflow.experimentKind``),
        so the MLflow UI opens it on its runs table rather than the GenAI traces view. Two
        invocations creating it at once: the loser reads the winner's experiment.
        """
        exp = self.call(self.client.get_experiment_by_name, name, write=False)
        if exp is None and create:
            try:
                exp_id = self.call(self.client.create_experiment, name, tags={EXPERIMENT_KIND: TRAINING_KIND})
                return exp_id
            except Exception as exc:  # RESOURCE_ALREADY_EXISTS from a concurrent creator
                exp = self.call(self.client.get_experiment_by_name, name, write=False)
                if exp is None:
                    raise exc from None
        if exp is None:
            return None
        if create and EXPERIMENT_KIND not in exp.tags:  # made by an older harness
            self.call(self.client.set_experiment_tag, exp.experiment_id, EXPERIMENT_KIND, TRAINING_KIND)
        return exp.experiment_id

    def set_experiment_tags(self, experiment_id: str, tags: dict[str, str]) -> None:
        """Set (or update) tags of an experiment, e.g. its description and saved view."""
        for key, value in tags.items():
            self.call(self.client.set_experiment_tag, experiment_id, key, value)

    def create_run(self, experiment_id: str, run_name: str, tags: dict[str, str]) -> str:
        run = self.call(self.client.create_run, experiment_id, tags=tags, run_name=run_name)
        return run.info.run_id

    def search(self, experiment_id: str, filter_string: str = "") -> list[Any]:
        """Every run of the experiment matching ``filter_string`` (all pages)."""
        runs: list[Any] = []
        token = None
        while True:
            page = self.call(
                self.client.search_runs,
                [experiment_id],
                filter_string=filter_string,
                max_results=1000,
                page_token=token,
                write=False,
            )
            runs.extend(page)
            token = page.token
            if not token:
                return runs

    def log_batch(
        self,
        run_id: str,
        metrics: list[Any] = (),  # type: ignore[assignment]
        params: dict[str, str] | None = None,
        tags: dict[str, str] | None = None,
    ) -> None:
        """Log in chunks that respect MLflow's per-batch limits."""
        from mlflow.entities import Param, RunTag

        p_items = [Param(k, str(v)[:6000]) for k, v in (params or {}).items()]
        t_items = [RunTag(k, str(v)[:TAG_MAX_CHARS]) for k, v in (tags or {}).items()]
        for i in range(0, len(p_items), PARAMS_PER_BATCH):
            self.call(self.client.log_batch, run_id, params=p_items[i : i + PARAMS_PER_BATCH])
        for i in range(0, len(t_items), PARAMS_PER_BATCH):
            self.call(self.client.log_batch, run_id, tags=t_items[i : i + PARAMS_PER_BATCH])
        metrics = list(metrics)
        for i in range(0, len(metrics), METRICS_PER_BATCH):
            self.call(self.client.log_batch, run_id, metrics=metrics[i : i + METRICS_PER_BATCH])

    def log_artifact(self, run_id: str, path: Path, artifact_path: str | None = None) -> None:
        fn = self.client.log_artifacts if path.is_dir() else self.client.log_artifact
        self.call(fn, run_id, str(path), artifact_path, write=False)

    def artifact_files(self, run_id: str, path: str) -> list[str]:
        """Every artifact file of the run under ``path`` (recursively), as artifact paths."""
        files = []
        for info in self.call(self.client.list_artifacts, run_id, path, write=False):
            files.extend(self.artifact_files(run_id, info.path) if info.is_dir else [info.path])
        return files

    def copy_artifacts(self, run_id: str, paths: list[str], folder: Path, under: str = "") -> list[Path]:
        """Copy the run's artifact files ``paths`` into ``folder``, each at its path below ``under``
        (``diagnostics/a/x.png`` with ``under="diagnostics"``: ``folder/a/x.png``; parents
        created), without MLflow's download progress bar; returns the copies in order."""
        import shutil
        import tempfile

        os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")  # else one bar per file
        copies = []
        with tempfile.TemporaryDirectory() as tmp:
            for path in paths:
                target = folder / Path(path).relative_to(under)
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(self.call(self.client.download_artifacts, run_id, path, tmp, write=False), target)
                copies.append(target)
        return copies

    def status(self, run_id: str) -> str:
        """The run's status (RUNNING, FINISHED, FAILED, KILLED)."""
        return self.call(self.client.get_run, run_id, write=False).info.status

    def delete_run(self, run_id: str) -> None:
        """Soft-delete a run (searches no longer see it); used to withdraw a lease claim."""
        self.call(self.client.delete_run, run_id)

    def log_inputs(self, run_id: str, datasets: list[Any], attempts: int = 4) -> None:
        """Log MLflow ``DatasetInput`` entities.

        Runs of one scene starting at the same moment race to insert the same dataset row
        (MLflow checks, then inserts: the loser gets an integrity error, over HTTP a 500);
        a retry finds the row and links it.
        """
        for attempt in range(attempts):
            try:
                self.call(self.client.log_inputs, run_id, datasets=datasets)
                return
            except Exception:
                if attempt == attempts - 1:
                    raise
                time.sleep(0.2 * (attempt + 1))

    def terminate(self, run_id: str, status: str, tags: dict[str, str] | None = None) -> None:
        """Set final tags and status (FINISHED, FAILED or KILLED)."""
        if tags:
            self.log_batch(run_id, tags=tags)
        self.call(self.client.set_terminated, run_id, status)
