"""Leases: claim a run before training it, so that several invocations can share one store.

A child run is its own claim. ``acquire`` creates it RUNNING with the lease tags
``lease.owner`` (host:pid), ``lease.heartbeat`` (unix seconds) and ``lease.seconds`` (how long
the claim lives without a heartbeat); the worker's ``Heartbeat`` thread refreshes
``lease.heartbeat`` every ``lease.seconds / 5``. A RUNNING run is *live* while its last
heartbeat is younger than its own ``lease.seconds``, else *stale* (its worker was killed,
its node was lost). A claim whose holder is a process of this host that no longer exists
(``holder_gone``: same host name, no such pid) is stale at once, whatever its heartbeat says: a
killed invocation's runs are taken over by the next one without waiting out the lease. Another
invocation:

- skips a (variant, scene, seed, config_hash) that has a FINISHED run or a live claim;
- takes over a stale claim: it marks it FAILED (``failure=interrupted``, the lease's age in
  ``error``) and records the takeover on its own claim (``lease.took_over``).

MLflow has no compare-and-set, so two invocations may claim the same run at the same
moment. Each claimer therefore creates its claim first and looks second: one that sees
any other live claim (or a FINISHED run) for its key withdraws (its claim is deleted),
waits a random moment and looks again. Of two simultaneous claimers at least the later
one sees the other, so at most one proceeds; if both withdraw, the random waits separate
them. Heartbeats carry the worker's clock: nodes must keep their clocks in sync to within
a small part of the lease (NTP does this on every cluster).
"""

from __future__ import annotations

import os
import random
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any

from harness.tracking.records import RunRecord, find_key_runs
from harness.tracking.store import Store

OWNER = "lease.owner"
HEARTBEAT = "lease.heartbeat"
SECONDS = "lease.seconds"
TOOK_OVER = "lease.took_over"
DEFAULT_LEASE_S = 300.0
ENV_LEASE_S = "FTGSPP_LEASE_S"
MAX_ATTEMPTS = 8


def lease_seconds(explicit: float | None = None) -> float:
    """The lease length: ``--lease`` if given, else ``$FTGSPP_LEASE_S``, else 300 s."""
    value = explicit if explicit is not None else float(os.environ.get(ENV_LEASE_S, DEFAULT_LEASE_S))
    if value <= 0:
        raise ValueError("lease must be positive")
    return float(value)


def owner_id() -> str:
    """Who holds a claim: ``host:pid``."""
    return f"{socket.gethostname()}:{os.getpid()}"


def heartbeat_age(rec: RunRecord, now: float | None = None) -> float:
    """Seconds since the run's last heartbeat (its start time when it has none)."""
    now = time.time() if now is None else now
    try:
        beat = float(rec.tags[HEARTBEAT])
    except (KeyError, ValueError):
        beat = rec.start_time / 1000.0
    return max(0.0, now - beat)


def lease_length(rec: RunRecord, default_lease_s: float = DEFAULT_LEASE_S) -> float:
    """The run's own lease in seconds (a run from before leases: ``default_lease_s``)."""
    try:
        return float(rec.tags[SECONDS])
    except (KeyError, ValueError):
        return default_lease_s


def holder(rec: RunRecord) -> tuple[str, int | None]:
    """(host, pid) of the claim's holder; pid None when the owner tag does not say."""
    host, _, pid = rec.tags.get(OWNER, "").rpartition(":")
    return (host, int(pid)) if host and pid.isdigit() else (rec.tags.get(OWNER, ""), None)


def holder_gone(rec: RunRecord) -> bool:
    """Whether the claim's holder was a process of this host (same host name) that no longer
    runs. A holder on another host, or one whose owner tag names no pid, is never judged gone."""
    import psutil

    host, pid = holder(rec)
    if pid is None or host != socket.gethostname():
        return False
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True
    except psutil.Error:  # e.g. access denied: it exists
        return False


def is_live(rec: RunRecord, default_lease_s: float = DEFAULT_LEASE_S, now: float | None = None) -> bool:
    """A RUNNING run whose last heartbeat is younger than its own lease and whose holder has not
    gone (``holder_gone``)."""
    if rec.status != "RUNNING":
        return False
    return heartbeat_age(rec, now) <= lease_length(rec, default_lease_s) and not holder_gone(rec)


def expires_in(rec: RunRecord, default_lease_s: float = DEFAULT_LEASE_S, now: float | None = None) -> float:
    """Seconds until the claim expires unless its holder beats again (negative: expired)."""
    return lease_length(rec, default_lease_s) - heartbeat_age(rec, now)


def describe(rec: RunRecord, now: float | None = None) -> str:
    """``host:pid, heartbeat 12s ago`` for status lines (``holder gone`` when it is)."""
    gone = ", holder gone" if rec.status == "RUNNING" and holder_gone(rec) else ""
    return f"{rec.tags.get(OWNER, 'unknown owner')}, heartbeat {heartbeat_age(rec, now):.0f}s ago{gone}"


def held_line(rec: RunRecord, default_lease_s: float = DEFAULT_LEASE_S, now: float | None = None) -> str:
    """One line naming a live claim's run, holder (host, pid) and when its lease expires."""
    now = time.time() if now is None else now
    host, pid = holder(rec)
    left = max(0.0, expires_in(rec, default_lease_s, now))
    at = time.strftime("%H:%M:%S", time.localtime(now + left))
    t = rec.tags
    label = f"{t['variant']}/{t['scene']}/seed{t['seed']}" if {"variant", "scene", "seed"} <= t.keys() else rec.run_id
    return (f"held: {label} by host {host or 'unknown'}, pid {pid or 'unknown'}"
            f" (heartbeat {heartbeat_age(rec, now):.0f}s ago); its lease expires at {at} (in {left:.0f}s)"
            " unless the holder beats again")


@dataclass(frozen=True)
class Claim:
    """The outcome of ``acquire``: a run id to train under, or why the run was skipped."""

    run_id: str | None
    reason: str = ""  # when skipped: "finished" or "claimed by host:pid, heartbeat ..."
    took_over: tuple[str, ...] = ()


def _take_over(store: Store, stale: list[RunRecord], me: str, lease_s: float) -> list[str]:
    taken = []
    for rec in stale:
        store.terminate(rec.run_id, "FAILED", {
            "failure": "interrupted",
            "error": f"lease expired ({describe(rec)}, lease {rec.tags.get(SECONDS, lease_s)}s);"
                     f" taken over by {me}",
        })
        taken.append(rec.run_id)
    return taken


def counts_as_done(rec: RunRecord, trainer: str = "") -> bool:
    """A FINISHED run, unless it was scored without LPIPS (weights missing then) and the weights
    exist now (a new run fills the LPIPS columns in), or ``trainer`` is given and the run was
    made by another trainer fingerprint (``study run --rerun-stale``: the code changed), not one
    recorded to train the same bits (``tracking.provenance.same_bits``)."""
    from harness.tracking.provenance import same_bits

    if rec.status != "FINISHED":
        return False
    if trainer and rec.tags.get("trainer_fingerprint") not in same_bits(trainer):
        return False
    if rec.metrics.get("lpips_missing") != 1.0:
        return True
    from ftgspp.lpips import weights_present

    return not weights_present()


def acquire(store: Store, experiment_id: str, run_name: str, tags: dict[str, str], lease_s: float,
            owner: str | None = None, rng: random.Random | None = None, trainer: str = "") -> Claim:
    """Claim the run whose key is in ``tags`` (study, variant, scene, seed, config_hash).

    Returns a ``Claim`` with the new RUNNING run's id, or with ``run_id=None`` and the reason
    when the run is finished or live elsewhere. Stale claims are taken over (see module doc).
    """
    me = owner or owner_id()
    rng = rng or random.Random()
    took_over: list[str] = []
    for attempt in range(MAX_ATTEMPTS):
        runs = find_key_runs(store, experiment_id, tags)
        if any(counts_as_done(r, trainer) for r in runs):
            return Claim(None, "finished")
        live = [r for r in runs if is_live(r, lease_s)]
        if live:
            return Claim(None, f"claimed by {describe(live[0])}")
        took_over += _take_over(store, [r for r in runs if r.status == "RUNNING"], me, lease_s)  # stale or gone
        now = time.time()
        claim_tags = {**tags, OWNER: me, HEARTBEAT: f"{now:.3f}", SECONDS: f"{lease_s:g}"}
        if took_over:
            claim_tags[TOOK_OVER] = ",".join(took_over)
        run_id = store.create_run(experiment_id, run_name, claim_tags)
        others = [r for r in find_key_runs(store, experiment_id, tags)
                  if r.run_id != run_id and (counts_as_done(r, trainer) or is_live(r, lease_s))]
        if not others:
            return Claim(run_id, took_over=tuple(took_over))
        store.delete_run(run_id)  # someone claimed at the same moment: withdraw, look again
        time.sleep(rng.uniform(0.05, 0.5) * (attempt + 1))
    return Claim(None, "contended: other invocations kept claiming it")


class Heartbeat:
    """A daemon thread refreshing ``lease.heartbeat`` of one run until ``stop()``.

    Created inside the worker (never pickled). A failed write is retried at the next beat;
    if the run is no longer RUNNING (taken over after a long silence) ``lost`` is set.
    """

    def __init__(self, store: Store, run_id: str, lease_s: float) -> None:
        self.store = store
        self.run_id = run_id
        self.interval_s = lease_s / 5.0
        self.lost = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"lease-{run_id[:8]}", daemon=True)

    def _loop(self) -> None:
        while not self._stop.wait(self.interval_s):
            try:
                if self.store.status(self.run_id) != "RUNNING":
                    self.lost = True
                    return
                self.store.log_batch(self.run_id, tags={HEARTBEAT: f"{time.time():.3f}"})
            except Exception:  # a store hiccup: the next beat tries again
                continue

    def __enter__(self) -> "Heartbeat":
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def stop(self) -> None:
        """Stop beating (waits for a write in progress)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
