"""One attempt at one job, seen from the worker (the parent of the training process).

The parent holds the lease: a heartbeat thread renews it and reads the cancel flag, and
the main thread turns the child's messages (worker/child.py) into fenced writes. If the
lease is lost (a heartbeat or any write matches no row) the child is killed at once and
nothing more is published. The child runs under ``multiprocessing`` *spawn*, so a crash
or a hang of the training cannot stop the heartbeats.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from dataclasses import dataclass, field

from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError, SQLAlchemyError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError

from modsat_core.agent.onnx_meta import stamp_job_id
from modsat_core.spec.jobspec import SpecError, parse_spec
from modsat_core.spec.limits import check as check_limits

from .child import ORPHAN_EXIT_CODE, child_main
from .settings import WorkerSettings
from .store import Claim, JobStore

log = logging.getLogger("modsat.worker")


@dataclass
class _Flags:
    lost: threading.Event = field(default_factory=threading.Event)
    cancel: threading.Event = field(default_factory=threading.Event)
    done: threading.Event = field(default_factory=threading.Event)


def _transient(exc: SQLAlchemyError) -> bool:
    """A database outage (worth retrying), not a statement the database will always refuse."""
    return isinstance(exc, (OperationalError, InterfaceError, PoolTimeoutError)) or (
        isinstance(exc, DBAPIError) and exc.connection_invalidated
    )


def _exit_text(code: int | None) -> str:
    if code is None:
        return "did not exit"
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    if code == ORPHAN_EXIT_CODE:
        return "exited because its worker died"
    return f"exited with code {code}"


class Attempt:
    """Run ``claim`` in a child process until it finishes, fails, is cancelled or the lease is lost.

    ``shutdown`` is the worker's stop request: the training is asked to stop (it checkpoints),
    and the job goes back to the queue without counting as a failure."""

    def __init__(
        self,
        store: JobStore,
        claim: Claim,
        settings: WorkerSettings,
        worker_id: str,
        shutdown: threading.Event,
        hurry: threading.Event,
    ):
        self.store, self.claim, self.s, self.worker_id = store, claim, settings, worker_id
        self.shutdown, self.hurry = shutdown, hurry
        self.flags = _Flags()
        self.t0 = time.monotonic()

    # ------------------------------------------------------------------ heartbeat thread
    def _heartbeat_loop(self) -> None:
        assert self.s.heartbeat_s is not None  # WorkerSettings' validator sets it
        period = float(self.s.heartbeat_s)
        next_reap = time.monotonic() + self.s.lease_s
        while not self.flags.done.wait(period):
            try:
                beat = self.store.heartbeat(self.claim, lease_s=self.s.lease_s)
                if not beat.alive:
                    log.warning(
                        "job %s attempt %s: lease lost; stopping without publishing",
                        self.claim.job_id,
                        self.claim.attempt,
                    )
                    self.flags.lost.set()
                    return
                if beat.cancel_requested:
                    self.flags.cancel.set()
                self.store.touch_worker(self.worker_id, job_id=self.claim.job_id, ttl_s=self.s.lease_s)
                if time.monotonic() >= next_reap:  # other workers' dead jobs must not wait for an idle worker
                    next_reap = time.monotonic() + self.s.lease_s
                    for job_id, status in self.store.reap(retry_delay_s=self.s.retry_delay_s):
                        log.warning("job %s: lease expired; now %s", job_id, status)
            except SQLAlchemyError as exc:  # the lease may expire meanwhile; the next beat will tell
                log.error("heartbeat of job %s failed: %s", self.claim.job_id, exc)

    # ------------------------------------------------------------------ main
    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def run(self) -> str:
        """Returns the attempt's outcome (for logs): succeeded, failed, crashed, cancelled, released, lost."""
        c = self.claim
        try:
            spec = parse_spec(c.spec_json)
        except SpecError as exc:
            self.store.fail_permanently(c, error=f"stored spec is not valid for this worker: {exc}")
            return "failed"
        problems = check_limits(spec, self.s.limits())
        if problems:  # this worker's limits may be lower than those of the API that took the job
            self.store.fail_permanently(
                c, error="this worker's limits refuse the job: " + "; ".join(msg for _, msg in problems)
            )
            return "failed"
        # The heartbeat runs from here on: loading a large checkpoint must not cost the lease.
        beat = threading.Thread(target=self._heartbeat_loop, daemon=True, name=f"heartbeat-{c.job_id}")
        beat.start()
        proc = reader = None
        try:
            checkpoint = self._load_checkpoint() if c.checkpoint_env_steps is not None else None
            if self.flags.lost.is_set():
                return "lost"
            log.info(
                "job %s attempt %s: starting%s",
                c.job_id,
                c.attempt,
                f" from the checkpoint at {c.checkpoint_env_steps} env steps" if checkpoint else "",
            )
            ctx = mp.get_context("spawn")
            reader, writer = ctx.Pipe(duplex=False)
            stop = ctx.Event()
            proc = ctx.Process(
                target=child_main,
                name=f"modsat-job-{c.job_id}",
                daemon=True,
                args=(writer, stop, self.s.runner, c.spec_json, checkpoint, os.getpid(), self.s.torch_threads),
            )
            proc.start()
            writer.close()  # so that the child's exit shows as EOF here
            del checkpoint
            return self._supervise(proc, reader, stop)
        finally:
            self.flags.done.set()
            if proc is not None:
                if proc.is_alive():
                    proc.kill()
                proc.join(10)
                assert reader is not None  # opened before proc was made
                reader.close()
            beat.join(10)

    def _load_checkpoint(self) -> bytes | None:
        """The job's checkpoint, read again through a brief database outage (it is not the
        job's fault, so it must not cost one of its attempts); the heartbeat keeps the lease."""
        delay = 0.5
        for _ in range(8):
            try:
                return self.store.load_checkpoint(self.claim.job_id)
            except SQLAlchemyError as exc:
                if not _transient(exc) or self.flags.lost.is_set():
                    raise
                log.error(
                    "job %s: could not read its checkpoint (retrying in %.1f s): %s", self.claim.job_id, delay, exc
                )
                time.sleep(delay)
                delay = min(2 * delay, 10.0)
        return self.store.load_checkpoint(self.claim.job_id)

    def _supervise(self, proc, reader, stop) -> str:
        c = self.claim
        kill_at: float | None = None
        result: tuple | None = None
        while True:
            if self.flags.lost.is_set():
                proc.kill()
                return "lost"
            if not stop.is_set() and (self.flags.cancel.is_set() or self.shutdown.is_set()):
                why = "cancel requested" if self.flags.cancel.is_set() else "worker shutting down"
                log.info("job %s: %s; asking the training to stop", c.job_id, why)
                stop.set()
                kill_at = time.monotonic() + self.s.cancel_grace_s
            if kill_at is not None and (time.monotonic() >= kill_at or self.hurry.is_set()):
                log.warning("job %s: training did not stop in time; killing it", c.job_id)
                proc.kill()
                break
            if not reader.poll(0.2):
                if proc.exitcode is not None and not reader.poll(0.5):
                    break  # dead, and nothing more is coming (its pipe end may live on in a grandchild)
                continue
            try:
                msg = reader.recv()
            except (EOFError, OSError):
                break  # the child exited
            if msg[0] in ("result", "error"):
                result = msg
                continue  # read on until EOF, so the child has really exited
            if not self._publish(msg):
                proc.kill()
                return "lost"
        proc.join(10)
        return self._finish(result, proc.exitcode)  # heartbeats go on until the end is recorded

    def _publish(self, msg: tuple) -> bool:
        """Write one progress or checkpoint message; False if the fence says the lease is lost.

        A database error loses this one message (the next progress row or checkpoint will
        do); the heartbeat thread decides whether the lease survives the outage."""
        try:
            return self._publish_once(msg)
        except SQLAlchemyError as exc:
            log.error("job %s: could not store a %s message: %s", self.claim.job_id, msg[0], exc)
            return True

    def _publish_once(self, msg: tuple) -> bool:
        c = self.claim
        if msg[0] == "progress":
            data = dict(msg[1])
            data["elapsed_s"] = round(c.run_seconds + self.elapsed(), 3)
            ok = self.store.publish_progress(c, data) is not None
        elif msg[0] == "checkpoint":
            ok = self.store.save_checkpoint(c, int(msg[1]), msg[2])
            if ok:
                log.info("job %s: checkpoint at %s env steps (%d bytes)", c.job_id, msg[1], len(msg[2]))
        else:
            log.error("job %s: unknown message %r from the training process", c.job_id, msg[0])
            ok = True
        if not ok:
            self.flags.lost.set()
            log.warning("job %s attempt %s: fenced off (lease lost); publishing nothing more", c.job_id, c.attempt)
        return ok

    def _finish(self, result: tuple | None, exitcode: int | None) -> str:
        """Record the attempt's end. The final write is retried through a database outage
        (the heartbeat thread keeps the lease meanwhile): a finished training is not lost lightly.
        An error that a retry cannot cure (e.g. a value the database refuses) is raised: the
        worker then records a failed attempt instead of retrying for ever."""
        delay = 0.5
        while True:
            try:
                return self._finish_once(result, exitcode)
            except SQLAlchemyError as exc:
                if self.flags.lost.is_set():
                    return "lost"
                if not _transient(exc):
                    raise
                log.error(
                    "job %s: could not record the end of attempt %s (retrying in %.0f s): %s",
                    self.claim.job_id,
                    self.claim.attempt,
                    delay,
                    exc,
                )
                time.sleep(delay)
                delay = min(2 * delay, 10.0)

    def _finish_once(self, result: tuple | None, exitcode: int | None) -> str:
        c, dt = self.claim, self.elapsed()
        stopping = self.flags.cancel.is_set() or self.shutdown.is_set()
        if result is not None and result[0] == "result":
            info, files = result[1], result[2]
            if not info["stopped"]:
                files = stamp_job_id(files, c.job_id)  # the ONNX export names its job (docs/export.md)
                ok = self.store.complete(
                    c, files=files, summary=info.get("summary"), env_steps=info["env_steps"], attempt_seconds=dt
                )
                return "succeeded" if ok else "lost"
        elif result is not None and result[0] == "error" and not stopping and len(result) > 3 and result[3]:
            status = self.store.fail_permanently(
                c, error=f"training cannot run: {result[1]}", detail=result[2], attempt_seconds=dt
            )
            log.warning("job %s attempt %s: %s -> %s (no retry)", c.job_id, c.attempt, result[1], status)
            return "failed" if status else "lost"
        elif result is not None and result[0] == "error" and not stopping:
            status = self.store.fail_attempt(
                c,
                error=f"training raised {result[1]}",
                detail=result[2],
                outcome="failed",
                retry_delay_s=self.s.retry_delay_s,
                attempt_seconds=dt,
            )
            log.warning("job %s attempt %s: %s -> %s", c.job_id, c.attempt, result[1], status)
            return "failed" if status else "lost"
        elif not stopping:
            error = f"the training process {_exit_text(exitcode)}"
            status = self.store.fail_attempt(
                c, error=error, detail=None, outcome="crashed", retry_delay_s=self.s.retry_delay_s, attempt_seconds=dt
            )
            log.warning("job %s attempt %s: %s -> %s", c.job_id, c.attempt, error, status)
            return "crashed" if status else "lost"
        # Stopped (returned early, or killed after the grace period) because of a cancel or shutdown.
        if self.flags.cancel.is_set():
            ok = self.store.finish_cancelled(c, attempt_seconds=dt)
            return "cancelled" if ok else "lost"
        ok = self.store.release(c, attempt_seconds=dt)
        return "released" if ok else "lost"
