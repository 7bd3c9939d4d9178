"""Checkpoints: their codec (bytes that ``torch.load(weights_only=True)`` reads, old files
included), their version, the size up to which a replay buffer goes into one, and moving a run's
state to the CPU for one and back to its device on resume (docs/train-interface.md).
"""

from __future__ import annotations

import io

import numpy as np
import torch

from modsat_core.agent.policy_file import load_plain

try:
    from numpy._core import multiarray as np_multiarray  # numpy 2
except ImportError:  # numpy 1
    from numpy.core import multiarray as np_multiarray  # type: ignore[no-redef]

#: The replay buffer goes into checkpoints only up to this size (bigger buffers are refilled
#: after a resume: learning restarts after ``learning_starts`` fresh transitions).
CHECKPOINT_BUFFER_LIMIT_BYTES = 256 * 2**20
CHECKPOINT_VERSION = 2


def checkpoint_to_bytes(ckpt: dict) -> bytes:
    """A checkpoint as bytes that ``torch.load(weights_only=True)`` reads: tensors and plain
    data (numpy arrays and scalars become lists and numbers)."""
    buf = io.BytesIO()
    torch.save(_plain(ckpt), buf)
    return buf.getvalue()


def checkpoint_from_bytes(data: bytes) -> dict:
    """Read a checkpoint with ``torch.load(weights_only=True)``: a checkpoint can be downloaded
    (``/api/jobs/{id}/artifacts/checkpoint.pt``) and handed back (``modsat train --resume``), so
    a pickle that would build other objects (and could run code) is refused. Numpy integer
    arrays, which checkpoints before this rule held (the best design's grid), are allowed."""
    ckpt = load_plain(data, "checkpoint", allow=_NUMPY_ARRAYS)
    if not isinstance(ckpt, dict):
        raise ValueError("not a modsat checkpoint")
    return ckpt


#: What an older checkpoint's numpy grid needs from ``weights_only`` loading: the array
#: constructor (under numpy 2's and numpy 1's module names) and the array and dtype types.
_NUMPY_ARRAYS: list = [
    np.ndarray,
    np.dtype,
    *(type(np.dtype(t)) for t in (np.int64, np.int8, np.float64)),
    (np_multiarray._reconstruct, "numpy._core.multiarray._reconstruct"),
    (np_multiarray._reconstruct, "numpy.core.multiarray._reconstruct"),
]


def _map_leaves(x, leaf):
    """``x`` with ``leaf`` applied to everything that is not a dict, list or tuple."""
    if isinstance(x, dict):
        return {k: _map_leaves(v, leaf) for k, v in x.items()}
    if isinstance(x, list):
        return [_map_leaves(v, leaf) for v in x]
    if isinstance(x, tuple):
        return tuple(_map_leaves(v, leaf) for v in x)
    return leaf(x)


def _plain(x):
    """Numpy arrays and scalars as lists and numbers (what weights_only loading reads)."""

    def leaf(v):
        if isinstance(v, np.ndarray):
            return v.tolist()
        return v.item() if isinstance(v, np.generic) else v

    return _map_leaves(x, leaf)


def to_cpu(x):
    return _map_leaves(x, lambda v: v.detach().cpu() if isinstance(v, torch.Tensor) else v)


def to_device(x, device):
    return _map_leaves(x, lambda v: v.to(device) if isinstance(v, torch.Tensor) else v)
