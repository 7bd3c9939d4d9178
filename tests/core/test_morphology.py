"""Morphology: validity and mass properties, against hand calculations and the paper."""

import numpy as np
import pytest
import torch

from modsat_core.grid import (
    ACTUATOR,
    STRUCTURE,
    is_connected,
    is_valid,
    valid_mask,
    validity_problem,
)
from modsat_core.sim.morphology import (
    mass_properties,
    mass_properties_batched,
    seed_component_batched,
)

A, M = 0.1, 1.0


def test_single_module_is_m_a2_over_6():
    mp = mass_properties([[[2]]], M, A)
    assert mp.mass_kg == 1.0
    np.testing.assert_allclose(mp.inertia_B_kgm2, np.eye(3) * M * A**2 / 6, rtol=0, atol=1e-18)


def test_full_3x3x3_is_0_405_on_the_diagonal():
    mp = mass_properties(np.ones((3, 3, 3)), M, A)
    np.testing.assert_allclose(np.diag(mp.inertia_B_kgm2), [0.405] * 3, rtol=1e-12)
    np.testing.assert_allclose(mp.inertia_B_kgm2 - np.diag(np.diag(mp.inertia_B_kgm2)), 0, atol=1e-15)


def test_l_shape_products_of_inertia_match_hand_calculation():
    grid = np.zeros((2, 2, 2), dtype=int)
    grid[0, 0, 0] = ACTUATOR
    grid[1, 0, 0] = STRUCTURE
    grid[0, 1, 0] = STRUCTURE
    mp = mass_properties(grid, M, A)
    # Centre of mass at (a/3, a/3, 0); module offsets (-1,-1), (2,-1), (-1,2) in units of a/3.
    # sum x y = a^2/9 (1 - 2 - 2) = -a^2/3, so I_xy = -sum m x y = +a^2/3.
    a2 = A * A
    expected = np.array(
        [
            [3 * a2 / 6 + 2 * a2 / 3, a2 / 3, 0.0],
            [a2 / 3, 3 * a2 / 6 + 2 * a2 / 3, 0.0],
            [0.0, 0.0, 3 * a2 / 6 + 4 * a2 / 3],
        ]
    )
    np.testing.assert_allclose(mp.com_grid_m, [A / 3, A / 3, 0.0], rtol=1e-12)
    np.testing.assert_allclose(mp.inertia_B_kgm2, expected, rtol=1e-12, atol=1e-18)
    assert abs(mp.inertia_B_kgm2[0, 1]) > 1e-3  # products of inertia are really there


def paper_appendix_a(grid, m=M, size=A, swapped=False):
    """The paper's Appendix A, literally: positions (i-1)h, (j-1)l, -(k-1)w, centroid shift,
    then per-module diagonal terms (eq. ii; eq. iii when ``swapped``), summed."""
    cells = np.argwhere(np.asarray(grid) > 0) + 1  # 1-based (i, j, k)
    p_o = np.stack([(cells[:, 0] - 1) * size, (cells[:, 1] - 1) * size, -(cells[:, 2] - 1) * size], axis=1)
    p_bt = p_o - p_o.mean(axis=0)
    x, y, z = p_bt.T
    own = m * (size**2 + size**2) / 12
    if swapped:  # eq. (iii) as printed
        return np.array(
            [np.sum(own + m * (x**2 + z**2)), np.sum(own + m * (y**2 + z**2)), np.sum(own + m * (x**2 + y**2))]
        )
    return np.array([np.sum(own + m * (y**2 + z**2)), np.sum(own + m * (x**2 + z**2)), np.sum(own + m * (x**2 + y**2))])


def symmetric_designs(rng, n, count):
    out = []
    for _ in range(count):
        half = n // 2 + 1
        octant = rng.integers(0, 3, size=(half, half, half))
        g = np.zeros((n, n, n), dtype=int)
        for i in range(n):
            for j in range(n):
                for k in range(n):
                    g[i, j, k] = octant[abs(i - n // 2), abs(j - n // 2), abs(k - n // 2)]
        out.append(g)
    return out


@pytest.mark.parametrize("n", [3, 5])
def test_symmetric_designs_match_paper_appendix_a(n):
    rng = np.random.default_rng(n)
    designs = symmetric_designs(rng, n, 10)
    plus = np.zeros((n, n, n), dtype=int)
    c = n // 2
    plus[c, c, :] = plus[c, :, c] = plus[:, c, c] = STRUCTURE
    plus[c, c, c] = ACTUATOR
    designs += [np.ones((n, n, n), dtype=int), plus]
    for g in designs:
        if not (g > 0).any():
            continue
        I = mass_properties(g, M, A).inertia_B_kgm2
        np.testing.assert_allclose(np.diag(I), paper_appendix_a(g), rtol=1e-12)
        np.testing.assert_allclose(I - np.diag(np.diag(I)), 0, atol=1e-14)  # symmetric -> no products
        # eq. (iii) as printed swaps x and y in its first two rows; it agrees when the design
        # is also symmetric under exchanging the i and j axes.
        if np.array_equal(g, g.transpose(1, 0, 2)):
            np.testing.assert_allclose(np.diag(I), paper_appendix_a(g, swapped=True), rtol=1e-12)


def test_diagonal_equals_eq_ii_for_any_design():
    rng = np.random.default_rng(7)
    for _ in range(20):
        g = rng.integers(0, 3, size=(4, 4, 4))
        if (g > 0).any():
            np.testing.assert_allclose(
                np.diag(mass_properties(g, M, A).inertia_B_kgm2), paper_appendix_a(g), rtol=1e-12
            )


def test_validity_rules():
    g = np.zeros((3, 3, 3), dtype=int)
    assert validity_problem(g) == "it has no modules"
    g[0, 0, 0] = STRUCTURE
    assert "no actuator" in validity_problem(g)
    g[1, 1, 0] = ACTUATOR  # touches (0,0,0) only along an edge: not face-connected
    assert not is_connected(g) and not is_valid(g)
    g[1, 0, 0] = STRUCTURE
    assert is_valid(g)
    with pytest.raises(ValueError):
        validity_problem(np.full((2, 2, 2), 10))  # above the largest wheel type (MAX_CELL 9)
    with pytest.raises(ValueError):
        validity_problem(np.ones((2, 3, 2)))


def test_batched_matches_single_design_functions():
    rng = np.random.default_rng(11)
    grids = rng.choice([0, 0, 1, 2], size=(200, 3, 3, 3))
    grids[:50] = np.where(rng.random((50, 3, 3, 3)) < 0.8, 1, 0)
    grids[:50, 1, 1, 1] = 2
    valid = valid_mask(torch.tensor(grids)).numpy()  # the learning code's batched check, on tensors
    assert valid.any() and not valid.all()
    assert valid.tolist() == [is_valid(g) for g in grids]
    assert valid.tolist() == valid_mask(grids).tolist()  # the same function on numpy arrays
    mass, com, inertia = mass_properties_batched(torch.tensor(grids), M, A)
    for i, g in enumerate(grids):
        if (g > 0).any():
            mp = mass_properties(g, M, A)
            assert mass[i].item() == pytest.approx(mp.mass_kg)
            np.testing.assert_allclose(com[i].numpy(), mp.com_grid_m, atol=1e-15)
            np.testing.assert_allclose(inertia[i].numpy(), mp.inertia_B_kgm2, atol=1e-15)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_repair_keeps_the_seed_component_and_makes_every_design_valid(n):
    rng = np.random.default_rng(n)
    grids = torch.tensor(rng.integers(0, 3, size=(300, n, n, n)))
    grids[:20] = 0  # empty grids become the seed module alone
    fixed = seed_component_batched(grids)
    assert valid_mask(fixed).all()
    c = n // 2
    assert (fixed[:, c, c, c] == ACTUATOR).all()
    assert ((fixed == 0) | (fixed == grids) | (torch.arange(n**3).reshape(n, n, n) == (c * n + c) * n + c)).all()
    assert (fixed[:20] > 0).sum().item() == 20
    # Already valid with the seed in place: unchanged.
    assert torch.equal(seed_component_batched(fixed), fixed)
    # A module cut off from the seed is dropped, the rest kept.
    g = torch.zeros(1, 3, 3, 3, dtype=torch.long)
    g[0, 1, 1, 1], g[0, 1, 1, 2], g[0, 0, 0, 0] = ACTUATOR, STRUCTURE, ACTUATOR
    out = seed_component_batched(g)[0]
    assert out[1, 1, 2] == STRUCTURE and out[0, 0, 0] == 0
