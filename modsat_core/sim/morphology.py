"""Morphology: checks and mass properties of voxel satellites.

A design is an integer grid ``(N, N, N)``: 0 empty, 1 structure, 2 actuator (a 3-axis
reaction-wheel unit). A design is *valid* when its modules are face-connected
(6-neighbourhood) and it has at least one actuator: the rule is
:func:`modsat_core.grid.valid_mask`, torch-free, which also takes tensors.

Body frame B: origin at the centre of mass, axes along the grid's i, j, k index
directions (right-handed). The cell (i, j, k) has its centre at ``a * (i, j, k)`` in grid
coordinates, before the shift to the centre of mass. (The paper's reference frame flips
the third axis; that changes no moment of inertia.)

Inertia tensor convention: ``I = sum_m [ m a^2/6 E + m (|r|^2 E - r r^T) ]``, so the
off-diagonal entries are the *negatives* of the products of inertia ``sum m x y``.

Single-design functions use numpy (float64); the ``*_batched`` ones take torch tensors
``(B, N, N, N)`` for the learning code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from modsat_core.grid import ACTUATOR, as_grid, flood_fill
from modsat_core.spec.parts import cell_masses
from modsat_core.spec.sections import ModuleCatalog


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
        return self.positions_B_m[self.types >= ACTUATOR]

    def to_dict(self) -> dict:
        return {
            "mass_kg": self.mass_kg,
            "com_grid_m": self.com_grid_m.tolist(),
            "inertia_B_kgm2": self.inertia_B_kgm2.tolist(),
            "principal_moments_kgm2": np.linalg.eigvalsh(self.inertia_B_kgm2).tolist(),
            "modules": len(self.types),
            "actuators": int((self.types >= ACTUATOR).sum()),
        }


def mass_properties(design, module_mass_kg: float | np.ndarray = 1.0, module_size_m: float = 0.1) -> MassProperties:
    """Mass, centre of mass and full inertia tensor (products of inertia included). ``module_mass_kg``:
    every module's mass, or an (N, N, N) array of each cell's (:func:`~modsat_core.spec.parts.cell_masses`)."""
    grid = as_grid(design)
    cells = np.argwhere(grid > 0)
    if len(cells) == 0:
        raise ValueError("an empty design has no mass properties")
    types = grid[tuple(cells.T)].astype(np.int64)
    a = float(module_size_m)
    p_grid = cells.astype(np.float64) * a
    if np.ndim(module_mass_kg) == 0:
        m = float(module_mass_kg)
        com = p_grid.mean(axis=0)
        r = p_grid - com
        own = m * a * a / 6.0  # a solid cube about any axis through its centre
        inertia = len(cells) * own * np.eye(3) + m * ((r * r).sum() * np.eye(3) - r.T @ r)
        total = m * len(cells)
    else:
        w = np.asarray(module_mass_kg, dtype=np.float64)[tuple(cells.T)]  # (M,)
        total = float(w.sum())
        com = (w[:, None] * p_grid).sum(axis=0) / total
        r = p_grid - com
        inertia = (w.sum() * a * a / 6.0 + (w * (r * r).sum(1)).sum()) * np.eye(3) - (w[:, None] * r).T @ r
    return MassProperties(
        mass_kg=total,
        com_grid_m=com,
        inertia_B_kgm2=inertia,
        positions_B_m=r,
        cells=cells,
        types=types,
    )


def design_mass_properties(design, modules: ModuleCatalog) -> MassProperties:
    """:func:`mass_properties` with the parts catalog's masses (structure, each wheel unit type, the
    payload); without a catalog, every module ``module_mass_kg`` (the same numbers as before it)."""
    if modules.wheels or modules.payload is not None:
        return mass_properties(design, cell_masses(design, modules), modules.module_size_m)
    return mass_properties(design, modules.module_mass_kg, modules.module_size_m)


# ----------------------------------------------------------------------------- batched


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
    reached = flood_fill(reached, filled)
    return torch.where(reached, g, torch.zeros_like(g))


def mass_properties_batched(
    grids: Tensor, module_mass_kg: float = 1.0, module_size_m: float = 0.1, dtype: torch.dtype = torch.float64
) -> tuple[Tensor, Tensor, Tensor]:
    """Batched mass properties: (B, N, N, N) -> mass (B,), com (B, 3), inertia (B, 3, 3).

    Designs with no module get mass 0, com 0 and the identity as a harmless inertia (the
    caller masks them out as invalid).
    """
    B = grids.shape[0]
    return mass_properties_of_occupancy((grids > 0).to(dtype).reshape(B, -1), module_mass_kg, module_size_m)


def mass_properties_of_occupancy(
    occ: Tensor, module_mass_kg: float = 1.0, module_size_m: float = 0.1
) -> tuple[Tensor, Tensor, Tensor]:
    """Mass properties of B grids given as occupancies (B, N^3), the cells in C order, each a number
    in [0, 1]: a module (1), none (0), or a relaxed grid's probability of one, a cell's mass scaled
    by it. Differentiable in ``occ``; on 0/1 occupancies it is the grid's mass properties. Returns
    mass (B,), com (B, 3) and the inertia about it (B, 3, 3); an empty row gets the identity."""
    B, dtype = occ.shape[0], occ.dtype
    N = round(occ.shape[1] ** (1.0 / 3.0))
    idx = torch.arange(N, device=occ.device, dtype=dtype) * module_size_m
    gi, gj, gk = torch.meshgrid(idx, idx, idx, indexing="ij")
    p = torch.stack((gi, gj, gk), dim=-1).reshape(-1, 3)  # (N^3, 3)
    count = occ.sum(dim=1)
    safe = count.clamp(min=1e-12)
    com = occ @ p / safe.unsqueeze(-1)  # (B, 3)
    r = p.unsqueeze(0) - com.unsqueeze(1)  # (B, N^3, 3)
    w = occ.unsqueeze(-1) * module_mass_kg
    rr = (w * r * r).sum(dim=(1, 2))  # (B,)
    outer = torch.einsum("bni,bnj->bij", w * r, r)
    eye = torch.eye(3, dtype=dtype, device=occ.device)
    own = module_mass_kg * module_size_m**2 / 6.0
    inertia = (count * own + rr).reshape(B, 1, 1) * eye - outer
    inertia = torch.where((count > 0).reshape(B, 1, 1), inertia, eye.expand(B, 3, 3))
    return count * module_mass_kg, com, inertia
