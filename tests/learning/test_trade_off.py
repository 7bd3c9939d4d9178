"""The trade-off (`diffsim-codesign` with `objective.trade_off_prices_s_per_kg`): one distribution per mass
price, one controller, the front of flown designs over mass and settling time, the kept design the
lightest that meets the requirements, the run's files and resume; the bench's front arithmetic."""

from __future__ import annotations

import json

import numpy as np

from modsat_core.bench.pareto import beats, random_designs
from modsat_core.grid import ACTUATOR, STRUCTURE, is_valid
from modsat_core.spec.jobspec import JobSpec
from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.diffsim_pareto import ParetoRun, hypervolume, nondominated
from modsat_core.training.train import train

WHEELS = [
    {"name": "small", "torque_Nm": 0.02, "momentum_Nms": 0.05, "mass_kg": 0.2, "power_W": 0.5},
    {"name": "big", "torque_Nm": 0.05, "momentum_Nms": 0.2, "mass_kg": 0.8, "power_W": 1.5},
]


def tiny_trade_off(**over) -> JobSpec:
    """A trade-off on a 2x2x2 grid that trains in seconds (mechanics, not quality)."""
    d: dict = {
        "name": "tiny-trade-off",
        "algorithm": "diffsim-codesign",
        "seed": 3,
        "design": {"grid_size": 2},
        "modules": {
            "module_mass_kg": 0.3,
            "wheels": WHEELS,
            "payload": {"cells": [[0, 0, 0], [0, 0, 1]], "mass_kg": 1.0},
        },
        "mission": {"episode_steps": 24, "tolerance_deg": 1.0, "slew_min_deg": 5, "slew_max_deg": 20},
        "requirements": {"settling_time_s": 1.9, "success": 0.5, "mass_budget_kg": 20.0, "power_budget_W": 30.0},
        "training": {"total_env_steps": 6 * 32, "eval_every_steps": 64, "eval_episodes": 3},
        "diffsim": {
            "batch_size": 8,
            "window_steps": 4,
            "episode_steps": 12,
            "substeps": 2,
            "hidden_sizes": [8],
            "design_batch": 8,
            "design_slews": 2,
            "design_every": 2,
        },
        "objective": {"trade_off_prices_s_per_kg": [0.01, 1.0]},
        "evaluation": {"episodes": 4, "trajectories": 1, "conditions": ["delay-1", "weak-wheels"]},
    }
    for key, value in over.items():
        section, _, field = key.partition("__")
        d[section][field] = value
    return JobSpec.model_validate(d)


def test_each_price_has_its_own_distribution_over_every_part():
    run = ParetoRun(tiny_trade_off())
    assert run.logits.shape == (2, 8, 4)  # prices, cells, {empty, structure, small, big}
    grids, raw = run.draw(64, 1)
    for g in grids:
        assert g[0, 0, 0] == g[0, 0, 1] == STRUCTURE
        assert set(np.unique(g)) <= {0, 1, 2, 3}
        if (g >= ACTUATOR).any():
            assert is_valid(g)
    assert {2, 3} <= set(np.unique(raw))  # both wheel types are drawn


def test_an_empty_prior_starts_every_distribution_sparse():
    run = ParetoRun(tiny_trade_off(diffsim__design_empty_prior=0.9))
    p = run.logits.detach().softmax(-1)
    assert np.allclose(p[..., 0], 0.9) and np.allclose(p[..., 1:], 0.1 / 3)
    uniform = ParetoRun(tiny_trade_off())
    assert np.allclose(uniform.logits.detach().softmax(-1), 0.25)
    _, raw = run.draw(256, 0)
    free = ~run.fixed
    assert abs(float((raw[:, free] == 0).mean()) - 0.9) < 0.03


def test_a_trade_off_run_returns_its_front_keeps_the_lightest_that_meets_and_resumes_the_same():
    spec = tiny_trade_off()
    records: list[dict] = []
    files = train(spec, on_progress=records.append).artifacts()
    # the final evaluation says what it flies: the candidates, each front design under the conditions, then
    # the kept design's four stages
    stages = [r["stage"] for r in records if r.get("phase") == "evaluating" and r.get("stage")]
    assert "candidate designs" in stages[0] and "under 2 flight conditions" in stages[1]
    assert [s[:4] for s in stages[-4:]] == ["1/4:", "2/4:", "3/4:", "4/4:"]
    curve = json.loads(files["curve.json"])
    front, selection = curve["front"], curve["selection"]
    assert "initial_design" not in curve  # the front is a trade-off's comparison, not the one cube
    assert front and len(curve["designs"]) == 3 and len(curve["designs"][0]["prices"]) == 2
    # the front is the non-dominated set, over (mass, median settling), of the candidates that land every
    # slew and are flight-ready (where none is: of those that land, each point saying it is not)
    landed = [s for s in selection if s["success"] >= 1.0] or selection
    ready = all(p["flight_ready"] for p in front)
    pool = [s for s in landed if s.get("flight_ready") is not False] if ready else landed
    pts = np.asarray([[s["mass_kg"], s["median_settling_s"]] for s in pool])
    want = sorted(s["mass_kg"] for s, k in zip(pool, nondominated(pts), strict=True) if k)
    assert [p["mass_kg"] for p in front] == want
    for p in front:  # each point flew every condition and got a verdict
        assert set(p["conditions"]) == {"delay-1", "weak-wheels"} and isinstance(p["meets"], bool)
        assert p["power_W"] is not None and p["power_W"] > 0
    kept = json.loads(files["design.json"])["grid"]
    meeting = [p for p in front if p["meets"]]
    if meeting:
        assert kept == min(meeting, key=lambda p: p["mass_kg"])["grid"]
    assert any(p["grid"] == kept for p in front)
    assert curve["kept"]["meets_requirements"] == bool(meeting)
    ev = json.loads(files["evaluation.json"])
    assert (
        ev["requirements"]["meets"]
        == all(
            ev["requirements"]["landed_within_settling_time"][k] >= 0.5 for k in ("nominal", "delay-1", "weak-wheels")
        )
        and ev["requirements"]["mass_kg"] <= 20.0
    )
    ref = (curve["front_reference"]["mass_kg"], curve["front_reference"]["settling_s"])
    assert ref[1] == 24 / 12 and curve["front_hypervolume"] == hypervolume(
        np.asarray([[p["mass_kg"], p["median_settling_s"]] for p in front]), ref
    )
    ckpts: list[dict] = []
    stops = iter([False, False, False, True])
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False))
    assert first.stopped
    resumed = train(spec, checkpoint=checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1])))
    assert resumed.artifacts()["curve.json"] == files["curve.json"]


def test_the_archive_keeps_the_non_dominated_draws_that_landed_and_feeds_the_candidates():
    # slews small enough that the draws land before the controller has learned anything
    run = ParetoRun(tiny_trade_off(mission__slew_min_deg=1.0, mission__slew_max_deg=2.0))
    seen: list[dict] = []
    update_archive = run.update_archive

    def spy(grids, flown, prices, episode_s):
        seen.extend(
            {"grid": g, "landed": bool(eps) and all(e["success"] for e in eps)}
            for g, eps in zip(grids, flown, strict=True)
        )
        update_archive(grids, flown, prices, episode_s)

    run.update_archive = spy
    for _ in range(8):
        run.update()
    assert len(seen) == 4 * 2 * 4  # 4 design updates, 2 prices, 4 draws each
    assert run.archive, "no draw landed every slew: the tiny mission is too hard to test the archive"
    pts = np.asarray([[p["mass_kg"], p["settling_s"]] for p in run.archive])
    assert nondominated(pts).all() and list(pts[:, 0]) == sorted(pts[:, 0])
    for p in run.archive:  # each point is a draw that landed every slew, priced by its distribution
        assert any(s["landed"] and np.array_equal(s["grid"], p["grid"]) for s in seen)
        assert p["price"] in run.prices
    cands = run.candidates()
    assert all(any(np.array_equal(p["grid"], g) for g, _ in cands) for p in run.archive)
    grids = [g.tobytes() for g, _ in cands]
    assert len(set(grids)) == len(grids)


def test_the_fronts_arithmetic():
    pts = np.asarray([[1.0, 5.0], [2.0, 3.0], [3.0, 4.0], [4.0, 1.0]])
    assert nondominated(pts).tolist() == [True, True, False, True]
    # (ref - point) rectangles' union: from ref (5, 6), points (1, 5), (2, 3), (4, 1)
    assert hypervolume(pts[[0, 1, 3]], (5.0, 6.0)) == 1 * 1 + 2 * 3 + 1 * 5 + 0
    front = [{"mass_kg": 2.0, "median_settling_s": 3.0}]
    better = {"mass_kg": 1.9, "median_settling_s": 2.9}  # 5 % and 3 % better: beats it
    close = {"mass_kg": 1.99, "median_settling_s": 2.0}  # 0.5 % lighter only: does not
    assert beats([better, close], front) == 1
    spec = tiny_trade_off()
    for g in random_designs(spec, 20, 0):
        assert is_valid(g) and g[0, 0, 0] == STRUCTURE


def test_the_ga_trains_each_design_its_own_controller_within_the_update_budget(monkeypatch):
    import modsat_core.bench.pareto as pareto

    calls: list[tuple[np.ndarray, int]] = []
    real = pareto.own_controller

    def spy(spec, grid, updates, seed):
        calls.append((np.asarray(grid), updates))
        return real(spec, grid, updates, seed)

    monkeypatch.setattr(pareto, "own_controller", spy)
    out = pareto.ga_inner_front(tiny_trade_off(), updates=8, slews=3, seed=0, bench_seed=5, population=2, per_design=2)
    # two generations of two designs, each its own controller of two updates: never past the budget
    assert out["designs_trained"] == len(calls) >= 3
    assert out["updates"] == 2 * len(calls) <= 8
    assert all(u == 2 for _, u in calls)
    assert all((g >= ACTUATOR).any() for g, _ in calls)
    assert len({g.tobytes() for g, _ in calls}) == len(calls)  # no design trained twice
    trained = {g.tobytes() for g, _ in calls}
    for p in out["front"]:  # the front: designs it trained that landed every bench slew
        assert np.asarray(p["grid"]).tobytes() in trained and p["success"] == 1.0
