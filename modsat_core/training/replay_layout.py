"""The replay buffer's fields in torch dtypes: the compact row of
:func:`modsat_core.spec.limits.replay_layout` (one table for the buffer and the memory limits)."""

from __future__ import annotations

import math

import torch

from modsat_core.spec.limits import replay_layout


def replay_fields(N: int, last_command: bool = False) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """The replay buffer's fields on an N^3 grid: the compact row of
    :func:`modsat_core.spec.limits.replay_layout` (the table the memory limits read), in torch dtypes;
    ``last_command``: with the observed state's last command (`training.observe_last_command`)."""
    return {name: (shape, getattr(torch, dt)) for name, (shape, dt) in replay_layout(N, last_command).items()}


def replay_buffer_bytes(N: int, capacity: int, last_command: bool = False) -> int:
    """Memory of a full replay buffer of ``capacity`` transitions on an N^3 grid."""
    return capacity * sum(
        math.prod(shape) * torch.empty((), dtype=dt).element_size()
        for shape, dt in replay_fields(N, last_command).values()
    )
