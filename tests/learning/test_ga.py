"""The GA baseline: valid and unique designs, the survivor schedule, the env-step budget."""

from __future__ import annotations

import json
import math

import numpy as np

from modsat_core.agent.diffsim_policy import DiffsimPolicy
from modsat_core.agent.policy_file import load_policy
from modsat_core.grid import is_valid
from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.ga import mutate, survivor_count
from modsat_core.training.train import train

from .conftest import tiny_spec


def test_ga_designs_schedule_and_budget():
    spec = tiny_spec(
        algorithm="ga",
        training__total_env_steps=1000,
        ga={
            "population_size": 5,
            "steps_per_design": 64,
            "survivor_start": 0.6,
            "survivor_end": 0.0,
            "mutation_rate": 0.3,
        },
    )
    result = train(spec)
    curve = json.loads(result.artifacts()["curve.json"])
    designs, generations = curve["designs"], curve["generations"]
    grids = [np.asarray(d["grid"]) for d in designs]
    assert all(is_valid(g) for g in grids)
    assert len({g.tobytes() for g in grids}) == len(grids)  # unique
    # Budget: every env step accounted for, and no more than the budget.
    assert sum(d["env_steps"] for d in designs) == result.env_steps
    assert 1000 - 8 < result.env_steps <= 1000  # whole batches of num_envs = 8, never over
    assert all(d["env_steps"] <= 64 for d in designs)
    # Schedule: linear from 0.6 to 0.0 in the share of the budget spent, at least 2 survivors.
    assert len(generations) >= 2
    for g in generations:
        frac = 0.6 - 0.6 * g["budget_share"]
        assert math.isclose(g["survivor_fraction"], frac, abs_tol=1e-12)
        assert g["survivors"] == min(max(2, math.ceil(5 * frac)), 4)
        assert g["survivors"] + g["children"] == 5
    assert generations[0]["survivors"] > generations[-1]["survivors"] or generations[-1]["survivors"] == 2
    # The best design is the one with the best fitness.
    best = max(designs, key=lambda d: d["fitness"])
    assert json.loads(result.artifacts()["design.json"])["grid"] == best["grid"]


def test_survivor_count_follows_the_linear_schedule():
    spec = tiny_spec(algorithm="ga", training__total_env_steps=1000, ga={"population_size": 12})
    assert survivor_count(spec.ga, spec.training, 0) == (8, 0.6)  # ceil(12 * 0.6) = 8
    n, f = survivor_count(spec.ga, spec.training, 500)
    assert math.isclose(f, 0.3) and n == 4
    assert survivor_count(spec.ga, spec.training, 1000)[0] == 2  # never fewer than 2


def test_mutation_rate():
    rng = np.random.default_rng(0)
    g = rng.integers(0, 3, size=(10, 10, 10))
    m = mutate(rng, g, 0.1)
    changed = (m != g).mean()
    assert 0.08 < changed < 0.12 and set(np.unique(m)) <= {0, 1, 2}


def test_ga_with_the_first_order_learner_inside():
    """`ga.inner` diffsim: each design gets its own diffsim-control run of `steps_per_design`
    env steps (whole updates of batch x window), the best design's controller is the run's
    policy, and a stopped GA resumes to the same result."""
    spec = tiny_spec(
        algorithm="ga",
        training__total_env_steps=7 * 32,
        training__eval_every_steps=10**6,
        ga={"population_size": 3, "steps_per_design": 64, "inner": "diffsim"},
        diffsim={"batch_size": 8, "window_steps": 4, "episode_steps": 12, "substeps": 2, "hidden_sizes": [8]},
    )
    result = train(spec)
    files = result.artifacts()
    designs = json.loads(files["curve.json"])["designs"]
    # 64 steps = 2 updates of 32 per design; the last design gets the 32 left
    assert [d["env_steps"] for d in designs] == [64, 64, 64, 32]
    assert result.env_steps == 7 * 32 and all(is_valid(np.asarray(d["grid"])) for d in designs)
    best = max(designs, key=lambda d: d["fitness"])
    assert json.loads(files["design.json"])["grid"] == best["grid"]
    policy, grid, _ = load_policy(files["policy.pt"])
    assert isinstance(policy, DiffsimPolicy) and grid.tolist() == best["grid"]
    ckpts: list[dict] = []
    stops = iter([False, False, True])
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False))
    assert first.stopped
    resumed = train(spec, checkpoint=checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1])))
    assert resumed.artifacts()["curve.json"] == files["curve.json"]
    assert resumed.artifacts()["evaluation.json"] == files["evaluation.json"]


def test_ga_on_the_priced_objective_keeps_the_payload():
    """`ga.fitness` objective: every design carries the payload, its fitness is minus its objective
    (seconds) flown by its own controller."""
    spec = tiny_spec(
        algorithm="ga",
        training__total_env_steps=4 * 32,
        training__eval_every_steps=10**6,
        ga={"population_size": 3, "steps_per_design": 32, "inner": "diffsim", "fitness": "objective"},
        diffsim={"batch_size": 8, "window_steps": 4, "episode_steps": 12, "substeps": 2, "hidden_sizes": [8]},
        objective={"module_price_s": 0.01, "wheel_price_s": 0.1, "payload_cells": [[0, 0, 0], [0, 0, 1]]},
    )
    designs = json.loads(train(spec).artifacts()["curve.json"])["designs"]
    assert len(designs) == 4
    for d in designs:
        g = np.asarray(d["grid"])
        assert is_valid(g) and g[0, 0, 0] == g[0, 0, 1] == 1
        assert d["fitness"] == -d["objective_s"] and d["objective_s"] > 0.01 * (g > 0).sum()
