"""The one place that sets torch's threads of a process (``modsat`` commands and the worker's
training child both call :func:`set_torch_threads`). Imports no torch itself."""

from __future__ import annotations

import os
import sys


def set_torch_threads(n: int) -> None:
    """Torch's intra-op threads of this process: ``n``. One per training process unless told
    otherwise (``--threads``, ``MODSAT_TORCH_THREADS``): torch's default (one per core) measured
    about 20x slower on a busy 2-core machine.

    Set in the environment (``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``: for a torch imported later
    and the processes this one starts) and in torch if it is loaded."""
    os.environ["OMP_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = str(n)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)
