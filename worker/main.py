"""The worker process: reap, claim, run an attempt, repeat.

Run it as ``modsat worker --db URL`` (or ``python -m worker``). SIGINT / SIGTERM: the
running training is asked to stop, checkpoints, and its job goes back to the queue; a
second signal stops without waiting for the training.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import sys
import threading
import time
import uuid

from pydantic import ValidationError
from sqlalchemy.exc import SQLAlchemyError

from .args import add_worker_arguments
from .attempt import Attempt
from .runners import runner_path
from .settings import WorkerSettings
from .store import Claim, JobStore

log = logging.getLogger("modsat.worker")


class Worker:
    """Pulls jobs from the store and runs them one at a time."""

    def __init__(self, settings: WorkerSettings, store: JobStore | None = None):
        runner_path(settings.runner)  # fail fast on a bad runner name
        self.s = settings
        self.store = store or JobStore(settings.resolved_db_url, busy_timeout_s=settings.sqlite_busy_timeout_s)
        self.hostname = socket.gethostname()[:150]
        self.id = f"{self.hostname}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        self.shutdown = threading.Event()  # finish: stop the training gracefully, requeue its job
        self.hurry = threading.Event()  # second signal: do not wait for the training

    def request_stop(self, *_args) -> None:
        if self.shutdown.is_set():
            self.hurry.set()
        self.shutdown.set()

    def watch_parent(self, parent_pid: int) -> None:
        """Stop when ``parent_pid`` is no longer our parent (``modsat serve`` was killed)."""

        def loop() -> None:
            while not self.shutdown.wait(1.0):
                if os.getppid() != parent_pid:
                    log.warning("parent process %s is gone; stopping", parent_pid)
                    self.request_stop()

        threading.Thread(target=loop, daemon=True, name="parent-watch").start()

    def run(self, *, max_jobs: int | None = None, idle_exit_s: float | None = None) -> int:
        """Work until stopped (or ``max_jobs`` attempts, or idle for ``idle_exit_s``). Returns 0."""
        ttl = max(self.s.lease_s, 3 * self.s.poll_s)
        assert self.s.heartbeat_s is not None  # WorkerSettings' validator sets it
        if not self._start(ttl):
            return 0
        log.info(
            "worker %s: database %s, runner %s, lease %.1f s",
            self.id,
            self.store.url_for_humans,
            self.s.runner,
            self.s.lease_s,
        )
        done = 0
        idle_since = time.monotonic()
        next_touch = 0.0
        failures_in_a_row = 0
        try:
            while not self.shutdown.is_set() and (max_jobs is None or done < max_jobs):
                try:
                    for job_id, status in self.store.reap(retry_delay_s=self.s.retry_delay_s):
                        log.warning("job %s: lease expired; now %s", job_id, status)
                    if time.monotonic() >= next_touch:
                        self.store.touch_worker(self.id, job_id=None, ttl_s=ttl)
                        next_touch = time.monotonic() + float(self.s.heartbeat_s)
                    claim = self.store.claim(self.id, lease_s=self.s.lease_s)
                    failures_in_a_row = 0
                except SQLAlchemyError as exc:
                    failures_in_a_row += 1
                    wait = min(self.s.poll_s * 2**failures_in_a_row, 30.0)
                    log.error("database error (retrying in %.0f s): %s", wait, exc)
                    self.shutdown.wait(wait)
                    continue
                if claim is None:
                    if idle_exit_s is not None and time.monotonic() - idle_since >= idle_exit_s:
                        break
                    self.shutdown.wait(self.s.poll_s)
                    continue
                outcome = self._run_attempt(claim, ttl)
                log.info("job %s attempt %s: %s", claim.job_id, claim.attempt, outcome)
                done += 1
                idle_since = time.monotonic()
        finally:
            try:
                self.store.worker_stopped(self.id)
            except SQLAlchemyError:
                pass
            self.store.dispose()
        log.info("worker %s: stopped", self.id)
        return 0

    def _start(self, ttl: float) -> bool:
        """Create the tables and register; waits for a database that is not up yet."""
        wait = self.s.poll_s
        while not self.shutdown.is_set():
            try:
                self.store.create_schema()
                self.store.register_worker(
                    self.id, hostname=self.hostname, pid=os.getpid(), runner=self.s.runner, ttl_s=ttl
                )
                return True
            except SQLAlchemyError as exc:
                log.error(
                    "cannot reach the job store %s (retrying in %.0f s): %s", self.store.url_for_humans, wait, exc
                )
                self.shutdown.wait(wait)
                wait = min(2 * wait, 30.0)
        return False

    def _run_attempt(self, claim: Claim, ttl: float) -> str:
        try:
            self.store.touch_worker(self.id, job_id=claim.job_id, ttl_s=ttl)
            return Attempt(self.store, claim, self.s, self.id, self.shutdown, self.hurry).run()
        except Exception as exc:  # a worker bug fails the attempt, not the worker
            log.exception("job %s attempt %s: worker error", claim.job_id, claim.attempt)
            try:
                self.store.fail_attempt(
                    claim,
                    error=f"worker error: {type(exc).__name__}: {exc}",
                    detail=None,
                    outcome="crashed",
                    retry_delay_s=self.s.retry_delay_s,
                    attempt_seconds=0.0,
                )
            except SQLAlchemyError:
                pass  # the lease will expire and the reaper will requeue the job
            return "worker-error"


def settings_from_args(args: argparse.Namespace) -> WorkerSettings:
    overrides = {
        k: v for k, v in {"db_url": args.db, "data_dir": args.data_dir, "runner": args.runner}.items() if v is not None
    }
    return WorkerSettings(**overrides)


def run_worker(args: argparse.Namespace) -> int:
    """``modsat worker``: run one worker in this process until SIGINT / SIGTERM."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s worker[%(process)d] %(levelname)s %(message)s")
    try:
        worker = Worker(settings_from_args(args))
    except (ValidationError, ValueError, SQLAlchemyError) as exc:
        print(f"modsat worker: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGINT, worker.request_stop)
    signal.signal(signal.SIGTERM, worker.request_stop)
    if args.exit_with_parent:
        worker.watch_parent(args.exit_with_parent)
    return worker.run(max_jobs=args.max_jobs, idle_exit_s=args.idle_exit)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m worker", description="Run one modsat worker.")
    add_worker_arguments(p)
    return run_worker(p.parse_args(argv))
