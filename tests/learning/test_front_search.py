"""The trade-off's local search (modsat_core/training/front_search.py): one-move neighbours that keep the
payload, a search that returns the non-dominated set of what it flew within its budget and improves on
a poor start, and a run whose candidates take the search's points and say what it flew."""

from __future__ import annotations

import json

import numpy as np

from modsat_core.grid import ACTUATOR, EMPTY, STRUCTURE
from modsat_core.sim.pd import PDController
from modsat_core.spec.jobspec import JobSpec
from modsat_core.training.diffsim_codesign import fixed_cells
from modsat_core.training.diffsim_pareto import nondominated
from modsat_core.training.front_search import local_search, neighbours
from modsat_core.training.train import train
from tests.learning.test_trade_off import WHEELS, tiny_trade_off


def plate_spec(**diffsim) -> JobSpec:
    """A 3x3x3 grid over a 3x3 payload plate (k = 0), two wheel types, slews PD lands."""
    return JobSpec.model_validate(
        {
            "name": "front-search",
            "algorithm": "diffsim-codesign",
            "seed": 5,
            "design": {"grid_size": 3},
            "modules": {
                "module_mass_kg": 0.3,
                "wheels": WHEELS,
                "payload": {"cells": [[i, j, 0] for i in range(3) for j in range(3)], "mass_kg": 0.5},
            },
            "mission": {"episode_steps": 120, "tolerance_deg": 1.0, "slew_min_deg": 10, "slew_max_deg": 30},
            "objective": {"trade_off_prices_s_per_kg": [0.1, 1.0]},
            "diffsim": {"design_slews": 4, "substeps": 2, **diffsim},
        }
    )


def test_neighbours_are_one_move_away_keep_the_payload_and_are_never_flown_twice():
    spec = plate_spec()
    fixed, types = fixed_cells(spec.design, spec.objective, spec.modules)
    g = np.where(fixed, types, EMPTY)
    g[1, 1, 1], g[1, 1, 2], g[0, 1, 1] = ACTUATOR, STRUCTURE, ACTUATOR + 1
    rng = np.random.default_rng(0)
    seen = {g.tobytes()}
    first = neighbours(g, 40, rng, seen, fixed, types, ACTUATOR + 2)
    assert len(first) == 40 and len({h.tobytes() for h in first}) == 40
    for h in first:
        assert (h[fixed] == STRUCTURE).all() and (h >= ACTUATOR).any()
        assert h.tobytes() in seen and not np.array_equal(h, g)
        changed = np.flatnonzero((h != g).reshape(-1))
        # one cell changed or two swapped; a cut-off module drops with the cell that held it
        assert 1 <= len(changed) <= 3 or (h[~fixed] != EMPTY).sum() < (g[~fixed] != EMPTY).sum()
    # the same parent again: none of the first ones comes back
    again = neighbours(g, 40, rng, seen, fixed, types, ACTUATOR + 2)
    assert not {h.tobytes() for h in again} & {h.tobytes() for h in first}


def test_the_search_returns_the_front_of_what_it_flew_within_its_budget_and_improves_a_poor_start():
    spec = plate_spec()
    fixed, types = fixed_cells(spec.design, spec.objective, spec.modules)
    # a poor start: the middle layer full of structure around a big wheel unit (heavy and slow)
    poor = np.where(fixed, types, EMPTY)
    poor[:, :, 1] = STRUCTURE
    poor[1, 1, 1] = ACTUATOR + 1
    rounds: list[int] = []
    front, flown = local_search(spec, PDController, [poor], 97, lambda n, _b: rounds.append(n))
    assert flown <= 97 and len(rounds) >= 3 and rounds[0] == 0
    assert front, "nothing the search flew landed every slew"
    pts = np.asarray([[p["mass_kg"], p["mean_time_s"]] for p in front])
    assert nondominated(pts).all() and list(pts[:, 0]) == sorted(pts[:, 0])
    assert all(p["start"] == 0 for p in front)
    start = next((p for p in front if np.array_equal(p["grid"], poor)), None)
    assert start is None, "the poor start stayed on the front"
    # a point of the front is lighter than the start and settles no later than it: the search improved on it
    own, _ = local_search(spec, PDController, [poor], 1)
    assert len(own) == 1
    assert any(p["mass_kg"] < own[0]["mass_kg"] and p["mean_time_s"] <= own[0]["mean_time_s"] for p in front)


def test_a_trade_off_run_adds_the_search_points_to_its_candidates_and_says_what_it_flew():
    spec = tiny_trade_off(diffsim__front_search_designs=24)
    records: list[dict] = []
    files = train(spec, on_progress=records.append).artifacts()
    curve = json.loads(files["curve.json"])
    search = curve["front_search"]
    assert 0 < search["designs_flown"] <= 24 and search["slews"] == 2
    stages = [r["stage"] for r in records if r.get("phase") == "evaluating" and r.get("stage")]
    assert any("local search" in s for s in stages)
    assert search["new_candidates"] <= search["front"]
    plain = json.loads(train(tiny_trade_off()).artifacts()["curve.json"])
    assert "front_search" not in plain
    # the same run without the search flies exactly the search's new candidates fewer
    assert len(curve["selection"]) == len(plain["selection"]) + search["new_candidates"]
