"""Per-cell features: a row's features do not depend on the batch it is in; phase parts."""

from __future__ import annotations

import numpy as np
import torch

from modsat_core.codesign.features import (
    N_COMMON,
    N_DESIGN,
    N_FEATURES,
    PhysState,
    cell_observation,
)


def _batch():
    rng = np.random.default_rng(0)
    grids = torch.as_tensor(rng.integers(0, 3, size=(4, 3, 3, 3)))
    steps = torch.tensor([0, 4, 10, 10])  # two designing rows, two flying (D = 10)
    q = torch.as_tensor(rng.normal(size=(4, 4)), dtype=torch.float32)
    phys = PhysState(
        q / q.norm(dim=-1, keepdim=True),
        torch.tensor([[1.0, 0, 0, 0]]).expand(4, 4),
        torch.as_tensor(rng.normal(size=(4, 3)) * 0.01, dtype=torch.float32),
        torch.as_tensor(rng.normal(size=(4, 27, 3)), dtype=torch.float32),
    )
    return grids, steps, phys


def test_rows_are_independent_of_their_batch_and_phases_are_zero_padded():
    grids, steps, phys = _batch()
    obs = cell_observation(grids, steps, 10, phys, 0.5)
    assert obs.x.shape == (4, 27, N_FEATURES)
    for i in range(4):
        one = PhysState(phys.q_BN[i : i + 1], phys.q_TN[i : i + 1], phys.omega_B[i : i + 1], phys.h_cells[i : i + 1])
        alone = cell_observation(grids[i : i + 1], steps[i : i + 1], 10, one, 0.5)
        torch.testing.assert_close(obs.x[i : i + 1], alone.x)
    design_part, control_part = obs.x[..., N_COMMON : N_COMMON + N_DESIGN], obs.x[..., N_COMMON + N_DESIGN :]
    assert design_part[2:].abs().sum() == 0 and control_part[:2].abs().sum() == 0
    assert design_part[:2].abs().sum() > 0 and control_part[2:].abs().sum() > 0
    # Progress d / D on every cell of a designing row.
    torch.testing.assert_close(design_part[1, :, -1], torch.full((27,), 0.4))
