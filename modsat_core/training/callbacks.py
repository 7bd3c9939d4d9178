"""The callbacks :func:`modsat_core.training.train.train` takes (docs/train-interface.md): progress
records, checkpoints, and the question whether to stop."""

from __future__ import annotations

from collections.abc import Callable

#: Called with a :class:`~modsat_core.artefacts.ProgressRecord` as a dict.
ProgressFn = Callable[[dict], None]
#: Called with a checkpoint (a dict; :mod:`modsat_core.training.checkpoint` turns it into bytes).
CheckpointFn = Callable[[dict], None]
#: Asked between batches: True stops the run at a checkpoint.
StopFn = Callable[[], bool]
