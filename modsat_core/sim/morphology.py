"""Morphology: checks and mass properties of voxel satellites.

A design is an integer grid ``(N, N, N)``: 0 empty, 1 structure, 2 actuator (a 3-axis
reaction-wheel unit). A design is *valid* when its modules are face-connected
(6-neighbourhood) and it has at least one actuator.

Body frame B: origin at the centre of mass, axes along the grid's i, j, k index
directions (right-handed). The cell (i, j, k) has its centre at ``a * (i, j, k)`` in grid
coordinates, before the shift to the centre of mass. (The paper's reference frame flips
the third axis; that changes no moment of inertia.)

Inertia tensor convention: ``I = sum_m [ m a^2/6 E + m (|r|^2 E - r r^T) ]``, so the
off-diagonal entries are the *negatives* of the products of inertia ``sum m x y``.

Single-design functions use numpy (float64); the ``*_batched`` twins take torch tensors
``(B, N, N, N)`` for the learning code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from modsat_core.grid import ACTUATOR, as_grid


@dataclass(frozen=True)
class MassProperties:
    """Mass properties of one design, SI units, body frame B at the centre of mass."""

    mass_kg: float
    com_grid_m: np.ndarray  # (3,) centre of mass in grid coordinates (cell (0,0,0) centre at origin)
    inertia_B_kgm2: np.ndarray  # (3, 3) about the centre of mass
    positions_B_m: np.ndarray  # (M, 3) module centres relative to the centre of mass
    cells: np.ndarray  # (M, 3) int grid indices of the modules, same order
    types: np.ndarray  # (M,) module types (1 or 2)

    @property
    def actuator_positions_B_m(self) -> np.ndarray:
        return self.positions_B_m[self.types == ACTUATOR]

    def to_dict(self) -> dict:
        return {
            "mass_kg": self.mass_kg,
            "com_grid_m": self.com_grid_m.tolist(),
            "inertia_B_kgm2": self.inertia_B_kgm2.tolist(),
            "principal_moments_kgm2": np.linalg.eigvalsh(self.inertia_B_kgm2).tolist(),
            "modules": len(self.types),
            "actuators": int((self.types == ACTUATOR).sum()),
        }


def mass_properties(design, module_mass_kg: float = 1.0, module_size_m: float = 0.1) -> MassProperties:
    """Mass, centre of mass and full inertia tensor (products of inertia included)."""
    grid = as_grid(design)
    cells = np.argwhere(grid > 0)
    if len(cells) == 0:
        raise ValueError("an empty design has no mass properties")
    types = grid[tuple(cells.T)].astype(np.int64)
    m, a = float(module_mass_kg), float(module_size_m)
    p_grid = cells.astype(np.float64) * a
    com = p_grid.mean(axis=0)
    r = p_grid - com
    own = m * a * a / 6.0  # a solid cube about any axis through its centre
    inertia = len(cells) * own * np.eye(3) + m * ((r * r).sum() * np.eye(3) - r.T @ r)
    return MassProperties(
        mass_kg=m * len(cells),
        com_grid_m=com,
        inertia_B_kgm2=inertia,
        positions_B_m=r,
        cells=cells,
        types=types,
    )


# ----------------------------------------------------------------------------- batched


def _flood_fill(reached: Tensor, filled: Tensor) -> Tensor:
    """Grow ``reached`` (B, N, N, N) bool by 6-neighbour dilation inside ``filled`` until it stops."""
    while True:
        grown = reached.clone()
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown[:, :, 1:] |= reached[:, :, :-1]
        grown[:, :, :-1] |= reached[:, :, 1:]
        grown[:, :, :, 1:] |= reached[:, :, :, :-1]
        grown[:, :, :, :-1] |= reached[:, :, :, 1:]
        grown &= filled
        if torch.equal(grown, reached):
            return reached
        reached = grown


def valid_mask_batched(grids: Tensor) -> Tensor:
    """Validity of B designs at once: (B, N, N, N) integer -> (B,) bool.

    Flood fill by repeated 6-neighbour dilation restricted to filled cells, started from
    one filled cell per design; at most N^3 iterations, usually about N.
    """
    filled = grids > 0
    B = grids.shape[0]
    flat = filled.reshape(B, -1)
    any_filled = flat.any(dim=1)
    first = flat.float().argmax(dim=1)
    reached = torch.zeros_like(flat)
    reached[torch.arange(B, device=grids.device), first] = any_filled
    reached = reached.reshape(filled.shape)
    reached = _flood_fill(reached, filled)
    connected = (reached == filled).reshape(B, -1).all(dim=1)
    has_act = (grids == ACTUATOR).reshape(B, -1).any(dim=1)
    return any_filled & connected & has_act


def seed_component_batched(grids: Tensor) -> Tensor:
    """Repair B designs so each is valid: the centre (seed) cell becomes an actuator and
    every module not face-connected to it is removed. (B, N, N, N) -> a new tensor."""
    g = grids.clone()
    N = g.shape[1]
    c = N // 2
    g[:, c, c, c] = ACTUATOR
    filled = g > 0
    reached = torch.zeros_like(filled)
    reached[:, c, c, c] = True
    reached = _flood_fill(reached, filled)
    return torch.where(reached, g, torch.zeros_like(g))


def mass_properties_batched(
    grids: Tensor, module_mass_kg: float = 1.0, module_size_m: float = 0.1, dtype: torch.dtype = torch.float64
) -> tuple[Tensor, Tensor, Tensor]:
    """Batched mass properties: (B, N, N, N) -> mass (B,), com (B, 3), inertia (B, 3, 3).

    Designs with no module get mass 0, com 0 and the identity as a harmless inertia (the
    caller masks them out as invalid).
    """
    B, N = grids.shape[0], grids.shape[1]
    occ = (grids > 0).to(dtype).reshape(B, -1)  # (B, N^3)
    idx = torch.arange(N, device=grids.device, dtype=dtype) * module_size_m
    gi, gj, gk = torch.meshgrid(idx, idx, idx, indexing="ij")
    p = torch.stack((gi, gj, gk), dim=-1).reshape(-1, 3)  # (N^3, 3)
    count = occ.sum(dim=1)
    safe = count.clamp(min=1.0)
    com = occ @ p / safe.unsqueeze(-1)  # (B, 3)
    r = p.unsqueeze(0) - com.unsqueeze(1)  # (B, N^3, 3)
    w = occ.unsqueeze(-1) * module_mass_kg
    rr = (w * r * r).sum(dim=(1, 2))  # (B,)
    outer = torch.einsum("bni,bnj->bij", w * r, r)
    eye = torch.eye(3, dtype=dtype, device=grids.device)
    own = module_mass_kg * module_size_m**2 / 6.0
    inertia = (count * own + rr).reshape(B, 1, 1) * eye - outer
    inertia = torch.where((count > 0).reshape(B, 1, 1), inertia, eye.expand(B, 3, 3))
    return count * module_mass_kg, com, inertia
