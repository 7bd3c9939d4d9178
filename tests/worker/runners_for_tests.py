"""Runners used only by the tests (named as ``tests.worker.runners_for_tests:NAME``)."""

from __future__ import annotations

import os
import signal

from worker.runners import checkpoint_from_bytes, checkpoint_to_bytes, simulated  # noqa: F401 - the runner's codec


def crash_once(spec, *, on_progress, on_checkpoint, should_stop, checkpoint=None):
    """The simulated run, but a first attempt (no checkpoint yet to resume from) dies by
    SIGKILL half-way, after its first checkpoint: a segfault / OOM kill of the training."""
    half = spec.training.total_env_steps // 2

    def progress(d: dict) -> None:
        on_progress(d)
        if checkpoint is None and d["env_steps"] >= half:
            os.kill(os.getpid(), signal.SIGKILL)

    return simulated(
        spec, on_progress=progress, on_checkpoint=on_checkpoint, should_stop=should_stop, checkpoint=checkpoint
    )


def long_file_name(spec, *, on_progress, on_checkpoint, should_stop, checkpoint=None):
    """A finished run with a file name longer than the artefact table takes (200 characters):
    PostgreSQL refuses to store it, whatever the number of retries."""
    from worker.runners import noop

    result = noop(spec, on_progress=on_progress, on_checkpoint=on_checkpoint, should_stop=should_stop)
    result.files["x" * 300 + ".json"] = b"{}"
    return result


def torch_threads(spec, *, on_progress, on_checkpoint, should_stop, checkpoint=None):
    """The noop run, reporting the torch threads the training process was given."""
    import torch

    from worker.runners import noop

    result = noop(spec, on_progress=on_progress, on_checkpoint=on_checkpoint, should_stop=should_stop)
    result.summary = {"threads": torch.get_num_threads(), "omp": os.environ.get("OMP_NUM_THREADS")}
    return result
