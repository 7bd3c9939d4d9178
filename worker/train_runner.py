"""A job's one code path, the default runner ``train``: :func:`modsat_core.training.train.train`,
then, for a finished run, the ``evaluation.viser`` recording of its evaluation slews
(web.viewer.recording, made from the run's own ``design.json`` and ``trajectories.json``) and,
where the spec asks (``evaluation.basilisk``), ``verification.json`` (modsat_core.verify.run).

The worker's training child runs it (worker/runners.py) and so does ``modsat train``
(server/cli/run.py). It loads torch: the worker imports it only in the training child."""

from __future__ import annotations

from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.result import RunResult
from modsat_core.training.train import train as _train
from modsat_core.verify.run import add_verification
from web.viewer.recording import add_recording

__all__ = ["RunResult", "checkpoint_from_bytes", "checkpoint_to_bytes", "train"]  # the runner and its codec


def train(spec, *, on_progress=None, on_checkpoint=None, should_stop=None, checkpoint=None) -> RunResult:
    """``modsat_core.training.train.train``, plus ``evaluation.viser`` (and ``verification.json``) among
    the files of a finished run."""
    result = _train(
        spec, on_progress=on_progress, on_checkpoint=on_checkpoint, should_stop=should_stop, checkpoint=checkpoint
    )
    if not result.stopped:
        add_recording(result.files)
        add_verification(result.files)
    return result
