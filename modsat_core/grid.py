"""The design grid without torch: cell types and validity.

A design is an integer grid ``(N, N, N)``: 0 empty, 1 structure, 2 actuator (a 3-axis
reaction-wheel unit). It is *valid* when its modules are face-connected (6-neighbourhood)
and it has at least one actuator. numpy only, so that validating a spec (the API process,
``modsat check``) and the viewer never import torch.

The rule is written once, in :func:`flood_fill` and :func:`valid_mask`, with the operators numpy
arrays and torch tensors share: the learning code runs the same functions on batches of tensors
(the co-design MDP, the features, the design repair of :mod:`modsat_core.sim.morphology`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Cell types of a design grid. A cell of ``ACTUATOR + k`` holds a wheel unit of the parts catalog's
#: wheel type ``k`` (``modules.wheels``, docs/requirements.md); without a catalog there is one type, 2.
EMPTY, STRUCTURE, ACTUATOR = 0, 1, 2
#: The most wheel types a parts catalog may list: the largest cell value is ``ACTUATOR + MAX_WHEEL_TYPES - 1``.
MAX_WHEEL_TYPES = 8
MAX_CELL = ACTUATOR + MAX_WHEEL_TYPES - 1


def flood_fill(reached: Any, filled: Any) -> Any:
    """Grow ``reached`` (B, N, N, N) bool by 6-neighbour dilation inside ``filled`` until it
    stops. numpy arrays or torch tensors: only the operators both have are used."""
    while True:
        grown = reached & filled  # a new array (reached lies inside filled)
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown[:, :, 1:] |= reached[:, :, :-1]
        grown[:, :, :-1] |= reached[:, :, 1:]
        grown[:, :, :, 1:] |= reached[:, :, :, :-1]
        grown[:, :, :, :-1] |= reached[:, :, :, 1:]
        grown &= filled
        if bool((grown == reached).all()):
            return reached
        reached = grown


def _connected(filled: Any) -> Any:
    """(B, N, N, N) bool -> (B,) bool: the flood fill from each design's first module (in
    row-major order) reaches all of them (true for an empty design)."""
    flat = filled.reshape(filled.shape[0], -1)
    first = flat & (flat.cumsum(1) == 1)
    return (flood_fill(first.reshape(filled.shape), filled) == filled).reshape(flat.shape).all(1)


def valid_mask(grids: Any) -> Any:
    """Validity of B designs at once: (B, N, N, N) integer -> (B,) bool, numpy or torch: some
    modules, all face-connected, one of them an actuator. At most N^3 dilations, usually about N."""
    B = grids.shape[0]
    filled = grids > 0
    has_act = (grids >= ACTUATOR).reshape(B, -1).any(1)
    return filled.reshape(B, -1).any(1) & _connected(filled) & has_act


def describe(modules: int, actuators: int) -> str:
    """A design's size in words ("27 modules, 1 actuator"), as the CLI, the viewer and the study report say it."""
    return f"{modules} module{'s' * (modules != 1)}, {actuators} actuator{'s' * (actuators != 1)}"


def as_grid(design) -> np.ndarray:
    """A design (nested lists or array) as an int8 array of shape (N, N, N)."""
    grid = np.asarray(design, dtype=np.int64)
    if grid.ndim != 3 or len(set(grid.shape)) != 1:
        raise ValueError(f"a design is an N x N x N grid; got shape {grid.shape}")
    if grid.size and (grid.min() < 0 or grid.max() > MAX_CELL):
        raise ValueError(
            f"design cells must be 0 (empty), 1 (structure) or 2..{MAX_CELL} (a wheel unit of the catalog's type 0..)"
        )
    return grid.astype(np.int8)


def is_connected(design) -> bool:
    """All modules form one face-connected (6-neighbour) component; an empty grid is not."""
    filled = as_grid(design)[None] > 0
    return bool(filled.any()) and bool(_connected(filled)[0])


def has_actuator(design) -> bool:
    return bool((as_grid(design) >= ACTUATOR).any())


def validity_problem(design) -> str | None:
    """None for a valid design, else a sentence saying what is wrong."""
    grid = as_grid(design)
    if not (grid > 0).any():
        return "it has no modules"
    if not has_actuator(grid):
        return "it has no actuator module (type 2 or above)"
    if not is_connected(grid):
        return "its modules are not face-connected"
    return None


def is_valid(design) -> bool:
    return validity_problem(design) is None


def random_design(rng: np.random.Generator, N: int) -> np.ndarray:
    """An N x N x N grid whose cells are empty, structure or actuator with equal chance (int64;
    usually not valid)."""
    return rng.integers(0, 3, size=(N, N, N)).astype(np.int64)


def random_valid_design(rng: np.random.Generator, N: int, max_draws: int = 100_000) -> np.ndarray:
    """A :func:`random_design` drawn again until it is valid: the distribution of the GA's first
    generation, and of the designs a design-conditioned controller learns to fly."""
    for _ in range(max_draws):
        grid = random_design(rng, N)
        if is_valid(grid):
            return grid
    raise RuntimeError(f"no valid {N}^3 design in {max_draws} random draws")
