"""The training child process: runs one attempt of one job and reports to its parent.

The child never touches the database. It sends plain messages over a one-way pipe and the
parent (which holds the lease and the fencing token) decides what gets published:

=========================================  ===============================================
message                                    meaning
=========================================  ===============================================
``("progress", dict)``                     an ``on_progress`` dict, made JSON-safe
``("checkpoint", env_steps, bytes)``       an ``on_checkpoint`` dict, serialised
``("result", info, {name: bytes})``        ``train`` returned; ``info`` has ``stopped``,
                                           ``env_steps`` and ``summary``
``("error", "Type: message", traceback,   ``train`` raised; ``permanent``: retrying cannot
permanent)``                                help (:class:`~modsat_core.spec.jobspec.UnrunnableSpec`)
=========================================  ===============================================

``should_stop`` is a multiprocessing Event that the parent sets on cancel or shutdown. A
watchdog thread ends the child if its parent dies (``kill -9`` of the worker): an orphaned
training must not keep burning CPU, and it could not publish anything anyway.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
import traceback
from typing import Any

from .jsonsafe import to_json

#: Exit code of a child whose parent died.
ORPHAN_EXIT_CODE = 70


def _watch_parent(parent_pid: int) -> None:
    while True:
        if os.getppid() != parent_pid:
            os._exit(ORPHAN_EXIT_CODE)
        time.sleep(0.5)


def _plain(d: Any) -> Any:
    """Only JSON types cross the pipe, so the parent never unpickles numpy or torch objects."""
    return json.loads(to_json(d))


def child_main(
    conn,
    stop_event,
    runner_name: str,
    spec_json: str,
    checkpoint: bytes | None,
    parent_pid: int,
    torch_threads: int = 1,
) -> None:
    """Entry point of the spawned process (see the module docstring for the protocol)."""
    # Ctrl-C in a terminal reaches the whole process group; the parent decides when we stop.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watch").start()
    permanent: tuple[type, ...] = ()
    try:
        from modsat_core.spec.jobspec import UnrunnableSpec, parse_spec
        from modsat_core.training.threads import set_torch_threads

        permanent = (UnrunnableSpec,)
        set_torch_threads(torch_threads)

        from .runners import load_runner

        runner = load_runner(runner_name)
        set_torch_threads(torch_threads)  # again: loading the runner may have imported torch
        spec = parse_spec(spec_json)
        resume = runner.checkpoint_from_bytes(checkpoint) if checkpoint is not None else None
        last_steps = [int(resume.get("env_steps", 0)) if isinstance(resume, dict) else 0]

        def on_progress(d: dict) -> None:
            d = _plain(d)
            last_steps[0] = int(d.get("env_steps") or last_steps[0])
            conn.send(("progress", d))

        def on_checkpoint(ckpt: dict) -> None:
            steps = ckpt.get("env_steps") if isinstance(ckpt, dict) else None
            conn.send(
                ("checkpoint", int(steps if steps is not None else last_steps[0]), runner.checkpoint_to_bytes(ckpt))
            )

        result = runner.train(
            spec, on_progress=on_progress, on_checkpoint=on_checkpoint, should_stop=stop_event.is_set, checkpoint=resume
        )
        stopped = bool(result.stopped)
        files = {} if stopped else {str(k): bytes(v) for k, v in result.artifacts().items()}
        info = {
            "stopped": stopped,
            "env_steps": int(result.env_steps),
            "summary": _plain(getattr(result, "summary", None)),
        }
        conn.send(("result", info, files))
    except BaseException as exc:  # every failure is reported, then the child exits
        try:
            conn.send(("error", f"{type(exc).__name__}: {exc}", traceback.format_exc(), isinstance(exc, permanent)))
        except OSError:  # the parent is gone; nobody to tell
            pass
    finally:
        conn.close()
