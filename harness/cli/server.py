"""``ftgspp-server``: a multi-user tracking server, ``mlflow server`` on PostgreSQL.

    ftgspp-server [--root DIR] [--host 127.0.0.1] [--port 5000] [--pg-port 5433] [--workers 4]
                  [--allowed-hosts HOST:PORT,...]

Initialises a PostgreSQL cluster in ``DIR/pgdata`` the first time (Debian's ``postgresql``
package: ``initdb``/``pg_ctl`` from ``/usr/lib/postgresql/<version>/bin``), starts it
listening on 127.0.0.1 only, creates the ``mlflow`` database, then runs ``mlflow server``
in the foreground with ``--backend-store-uri postgresql+psycopg://...`` and proxied
artifacts in ``DIR/artifacts`` (clients upload through the server: workers need no access
to the artifact folder). Ctrl-C / SIGTERM stops both. Workers then use
``tracking=server`` or ``tracking.uri=http://HOST:PORT``.

PostgreSQL refuses to run as root: as root the database folder is given to the
``postgres`` user and its commands run through ``runuser``. It accepts connections from
127.0.0.1 only (``trust``), so only processes on the server's machine - the MLflow server
- reach the database; users reach MLflow over HTTP. Bad set-ups (no PostgreSQL, a port in
use) end with one line and exit status 2.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

from ftgspp.errors import InputError, exit_on_input_error

DB_NAME = "mlflow"
DB_USER = "mlflow"


def pg_bindir() -> Path:
    """The folder with ``initdb`` and ``pg_ctl`` (newest Debian version, else PATH)."""
    versions = sorted(Path("/usr/lib/postgresql").glob("*/bin/initdb"),
                      key=lambda p: int(p.parts[-3]) if p.parts[-3].isdigit() else 0)
    if versions:
        return versions[-1].parent
    found = shutil.which("initdb")
    if found:
        return Path(found).parent
    raise InputError("postgresql", "initdb not found: install PostgreSQL (apt-get install postgresql)")


def _as_db_user(cmd: list[str]) -> list[str]:
    """Run ``cmd`` as the ``postgres`` user when we are root (PostgreSQL refuses root)."""
    return ["runuser", "-u", "postgres", "--", *cmd] if os.geteuid() == 0 else cmd


def _port_free(host: str, port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex((host, port)) != 0


def backend_uri(pg_port: int) -> str:
    """The SQLAlchemy URI of the ``mlflow`` database."""
    return f"postgresql+psycopg://{DB_USER}@127.0.0.1:{pg_port}/{DB_NAME}"


def start_database(root: Path, pg_port: int, echo=print) -> Path:
    """Initialise (once) and start PostgreSQL for ``root``; returns its data folder."""
    bindir = pg_bindir()
    data = root / "pgdata"
    sock = root / "pgsock"
    root.mkdir(parents=True, exist_ok=True)
    sock.mkdir(exist_ok=True)
    if os.geteuid() == 0:
        shutil.chown(root, "postgres")
        shutil.chown(sock, "postgres")
        if subprocess.run(["runuser", "-u", "postgres", "--", "test", "-w", str(root)]).returncode != 0:
            raise InputError("--root", f"{root} is not reachable by the postgres user (a parent folder is private);"
                             " pick a folder under a world-readable path")
    if not (data / "PG_VERSION").is_file():
        echo(f"initialising a PostgreSQL cluster in {data}")
        subprocess.run(_as_db_user([str(bindir / "initdb"), "-D", str(data), "-U", DB_USER, "--auth=trust",
                                    "-E", "UTF8"]), check=True, stdout=subprocess.DEVNULL)
    if not _port_free("127.0.0.1", pg_port):
        raise InputError("--pg-port", f"127.0.0.1:{pg_port} is in use (a PostgreSQL already running? pick another)")
    opts = f"-p {pg_port} -k {sock} -c listen_addresses=127.0.0.1"
    subprocess.run(_as_db_user([str(bindir / "pg_ctl"), "-D", str(data), "-o", opts, "-l", str(root / "postgres.log"),
                                "-w", "start"]), check=True, stdout=subprocess.DEVNULL)
    exists = subprocess.run(_as_db_user([str(bindir / "psql"), "-h", "127.0.0.1", "-p", str(pg_port), "-U", DB_USER,
                                         "-d", "postgres", "-tAc", f"SELECT 1 FROM pg_database WHERE datname='{DB_NAME}'"]),
                            check=True, capture_output=True, text=True).stdout.strip()
    if exists != "1":
        subprocess.run(_as_db_user([str(bindir / "createdb"), "-h", "127.0.0.1", "-p", str(pg_port), "-U", DB_USER,
                                    DB_NAME]), check=True)
    echo(f"PostgreSQL on 127.0.0.1:{pg_port} (data {data}, log {root / 'postgres.log'})")
    return data


def stop_database(data: Path) -> None:
    """``pg_ctl stop`` (fast shutdown)."""
    subprocess.run(_as_db_user([str(pg_bindir() / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop"]),
                   check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def serve(root: Path, host: str, port: int, pg_port: int, workers: int, allowed_hosts: str | None = None,
          echo=print) -> int:
    """Start PostgreSQL and ``mlflow server`` on it; block until interrupted, then stop both."""
    if not _port_free(host, port):
        raise InputError("--port", f"{host}:{port} is in use (another mlflow server? pick another port)")
    root = root.resolve()
    data = start_database(root, pg_port, echo)
    mlflow_bin = Path(sys.executable).with_name("mlflow")
    cmd = [str(mlflow_bin) if mlflow_bin.exists() else "mlflow", "server", "--host", host, "--port", str(port),
           "--workers", str(workers), "--backend-store-uri", backend_uri(pg_port),
           "--artifacts-destination", str(root / "artifacts")]
    if allowed_hosts:  # MLflow 3 answers only localhost unless told which Host headers to accept
        cmd += ["--allowed-hosts", allowed_hosts]
    echo(f"mlflow server at http://{host}:{port} (backend {backend_uri(pg_port)}, artifacts {root / 'artifacts'})")
    echo(f"workers: export MLFLOW_TRACKING_URI=http://{host}:{port}   # or study run ... tracking=server")
    proc = subprocess.Popen(cmd, start_new_session=True)

    def _stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _stop)
    try:
        return proc.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
        stop_database(data)
        echo("stopped mlflow server and PostgreSQL")


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``ftgspp-server``."""
    p = argparse.ArgumentParser(prog="ftgspp-server", description=__doc__.split("\n\n")[0])
    p.add_argument("--root", type=Path, default=Path("tracking-server"),
                   help="folder for the database and artifacts (default ./tracking-server)")
    p.add_argument("--host", default="127.0.0.1", help="address mlflow server listens on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=5000, help="mlflow server port (default 5000)")
    p.add_argument("--pg-port", type=int, default=5433, help="PostgreSQL port on 127.0.0.1 (default 5433)")
    p.add_argument("--workers", type=int, default=4, help="mlflow server worker processes (default 4)")
    p.add_argument("--allowed-hosts", default=None,
                   help="Host headers mlflow server accepts when --host is not 127.0.0.1, e.g. 'login1:5000,login1.site:5000'")
    args = p.parse_args(argv)
    try:
        return serve(args.root, args.host, args.port, args.pg_port, args.workers, args.allowed_hosts,
                     echo=lambda s: print(f"[server] {s}", flush=True))
    except InputError as err:
        exit_on_input_error(err)
    except subprocess.CalledProcessError as err:
        print(f"error: ftgspp-server: {' '.join(map(str, err.cmd[-3:]))} failed (exit {err.returncode});"
              f" see the logs under {args.root}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
