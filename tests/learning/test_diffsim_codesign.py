"""diffsim-codesign: the design distribution, its draws and the satellites they make, the run's
outputs and resume."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from modsat_core.agent.diffsim_policy import N_DESIGN_INPUTS, DiffsimPolicy
from modsat_core.agent.policy_file import load_policy
from modsat_core.grid import ACTUATOR, EMPTY, STRUCTURE, is_valid
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.morphology import mass_properties, mass_properties_of_occupancy
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import SlewSim
from modsat_core.spec.jobspec import JobSpec, SpecError, parse_spec
from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.diffsim_codesign import DiffsimCodesignRun, objective_s, satellites, score_designs
from modsat_core.training.train import train

PAYLOAD = [[0, 0, 0], [0, 0, 1]]


def tiny_codesign(**over) -> JobSpec:
    """A diffsim-codesign run on a 2x2x2 grid that trains in seconds (mechanics, not quality)."""
    d: dict = {
        "name": "tiny-codesign",
        "algorithm": "diffsim-codesign",
        "seed": 5,
        "design": {"grid_size": 2},
        "modules": {"torque_scale_Nm": 0.05, "actuator_model": "reaction-wheel"},
        "mission": {"episode_steps": 24, "tolerance_deg": 1.0},
        "training": {"total_env_steps": 6 * 32, "eval_every_steps": 64, "eval_episodes": 3},
        "diffsim": {
            "batch_size": 8,
            "window_steps": 4,
            "episode_steps": 12,
            "substeps": 2,
            "hidden_sizes": [8],
            "design_batch": 6,
            "design_slews": 2,
            "design_every": 2,
        },
        "objective": {"module_price_s": 0.01, "wheel_price_s": 0.1, "payload_cells": PAYLOAD},
        "evaluation": {"episodes": 3, "trajectories": 1},
    }
    for key, value in over.items():
        section, _, field = key.partition("__")
        d[section][field] = value
    return JobSpec.model_validate(d)


def test_draws_keep_the_payload_and_only_what_is_connected_to_it():
    run = DiffsimCodesignRun(tiny_codesign(diffsim__design_batch=64))
    grids, raw = run.draw(64)
    for g, r in zip(grids, raw, strict=True):
        assert g[0, 0, 0] == g[0, 0, 1] == STRUCTURE and r[0, 0, 0] == r[0, 0, 1] == STRUCTURE
        assert set(np.unique(g)) <= {EMPTY, STRUCTURE, ACTUATOR}
        assert np.all((g == r) | (g == EMPTY))  # a satellite only drops modules
        if (g == ACTUATOR).any():
            assert is_valid(g)
    # a module cut off from the payload is dropped
    lone = np.zeros((1, 2, 2, 2), dtype=np.int64)
    lone[0, 0, 0, :] = STRUCTURE
    lone[0, 1, 1, 1] = ACTUATOR
    assert satellites(lone, run.fixed, run.fixed_types)[0, 1, 1, 1] == EMPTY
    # the log-probability counts the free cells only, under the uniform start
    assert torch.allclose(run.log_prob(raw), torch.full((64,), 6 * np.log(1 / 3), dtype=torch.float64))


def test_the_objective_counts_time_failures_modules_and_wheels():
    obj = tiny_codesign().objective
    grid = np.zeros((2, 2, 2), dtype=np.int64)
    grid[0, 0, :] = STRUCTURE
    grid[0, 1, 0] = ACTUATOR
    episodes = [{"success": True, "settling_time_s": 3.0}, {"success": False, "settling_time_s": None}]
    assert objective_s(episodes, grid, obj, episode_s=10.0) == pytest.approx(6.5 + 3 * 0.01 + 0.1)


def test_a_run_learns_a_design_writes_every_output_and_resumes_the_same():
    spec = tiny_codesign()
    result = train(spec)
    files = result.artifacts()
    curve = json.loads(files["curve.json"])
    assert curve["algorithm"] == "diffsim-codesign"
    assert len(curve["designs"]) == 3  # 6 updates, a design update every 2
    assert all(r["valid_draws"] <= 6 and "mode" in r for r in curve["designs"])
    kept = json.loads(files["design.json"])["grid"]
    assert is_valid(np.asarray(kept)) and kept[0][0][0] == kept[0][0][1] == STRUCTURE
    assert any(s["grid"] == kept for s in curve["selection"])
    assert min(s["objective_s"] for s in curve["selection"]) == next(
        s["objective_s"] for s in curve["selection"] if s["grid"] == kept
    )
    policy, grid, _ = load_policy(files["policy.pt"])
    assert isinstance(policy, DiffsimPolicy) and policy.n_design == N_DESIGN_INPUTS
    assert grid.tolist() == kept
    # the paper's initial design, the full cube (centre wheel unit, payload structure), flown by the
    # trained controller on the candidates' validation slews: the same figure flown on its own
    cube = np.full((2, 2, 2), STRUCTURE)
    cube[1, 1, 1] = ACTUATOR
    ev = spec.evaluation
    alone = score_designs(spec, policy.double(), [cube], ev.episodes, ev.seed + 1, exact=True)[0]
    assert curve["initial_design"]["grid"] == cube.tolist()
    assert curve["initial_design"]["objective_s"] == pytest.approx(alone, rel=1e-9)
    assert {"policy_export.pt", "evaluation.json"} <= set(files)
    ckpts: list[dict] = []
    stops = iter([False, False, False, True])
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False))
    assert first.stopped
    resumed = train(spec, checkpoint=checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1])))
    assert resumed.artifacts()["curve.json"] == files["curve.json"]
    assert resumed.artifacts()["evaluation.json"] == files["evaluation.json"]


def test_a_run_too_short_for_a_design_update_keeps_the_design_it_flew():
    """No design update yet, the uniform distribution's mode empty (no wheel unit), no best draws: the kept
    design is the one the curve flew, not an error."""
    run = DiffsimCodesignRun(tiny_codesign())
    run.update()
    assert not run.best and not (run.mode() >= 2).any()
    _, grid, extra = run.chosen()
    assert is_valid(grid) and np.array_equal(grid, run.grid) and len(extra["selection"]) == 1
    assert extra["initial_design"]["grid"][1][1][1] == ACTUATOR


def test_no_initial_design_where_the_payload_covers_the_cubes_centre():
    """The cube's one wheel unit sits at the centre: a payload there leaves it no wheel, no comparison."""
    run = DiffsimCodesignRun(tiny_codesign(objective__payload_cells=[[1, 1, 1], [1, 1, 0]]))
    run.update()
    _, _, extra = run.chosen()
    assert "initial_design" not in extra and extra["selection"]


def test_a_run_trained_for_the_flight_conditions_keeps_a_flight_ready_design():
    """With ``randomise`` on, the candidates fly the conditions best objective first and the first that
    lands every condition is kept (here the first: every slew lands at a 180 deg, 10 rad/s tolerance); where none
    does, every candidate is flown and the best worst condition wins; a nominal run flies none."""
    conditions = ["delay-1", "weak-wheels"]
    spec = tiny_codesign(
        evaluation__conditions=conditions,
        mission__tolerance_deg=180.0,
        mission__rate_tolerance_rad_s=10.0,
        mission__rate_limit_rad_s=10.0,
    )
    spec = spec.model_copy(update={"randomise": spec.randomise.model_copy(update={"delay_steps": 1})})
    assert spec.randomise.active
    run = DiffsimCodesignRun(spec)
    grids = [g for g in run.draw(64)[0] if (g >= ACTUATOR).any()][:3]
    actor = run.policy.cpu().eval()
    scores = [3.0, 1.0, 2.0]

    selection: list[dict] = [{} for _ in grids]
    assert run.flight_ready_choice(actor, grids, scores, selection) == 1
    assert selection[1]["flight_ready"] and set(selection[1]["conditions"]) == set(conditions)
    assert "conditions" not in selection[0] and "conditions" not in selection[2]  # no flight after the first

    hard = tiny_codesign(evaluation__conditions=conditions, mission__tolerance_deg=0.001)
    run.spec = hard.model_copy(update={"randomise": spec.randomise})
    selection = [{} for _ in grids]
    kept = run.flight_ready_choice(actor, grids, scores, selection)
    assert all(not s["flight_ready"] for s in selection)  # every candidate flown, none lands
    worst = [min(s["conditions"].values()) for s in selection]
    assert worst[kept] == max(worst) and scores[kept] == min(sc for sc, w in zip(scores, worst) if w == max(worst))

    run.spec = hard  # trained nominally: the best objective, nothing flown
    selection = [{} for _ in grids]
    assert run.flight_ready_choice(actor, grids, scores, selection) == 1 and selection == [{}, {}, {}]


def test_the_payload_must_fit_the_grid_and_be_one_piece():
    with pytest.raises(SpecError, match="outside"):
        parse_spec({"design": {"grid_size": 2}, "objective": {"payload_cells": [[0, 0, 2]]}})
    with pytest.raises(SpecError, match="face-connected"):
        parse_spec({"objective": {"payload_cells": [[0, 0, 0], [2, 2, 2]]}})
    with pytest.raises(SpecError, match="distinct"):
        parse_spec({"objective": {"payload_cells": [[0, 0, 0], [0, 0, 0]]}})


#: The co-design learning test's budget: updates of 256 slews x 32 steps, a design update every 4
#: (docs/diffsim.md, "Co-design", has the measurements behind it).
CODESIGN_UPDATES = 64


def codesign_outcome(seed: int) -> dict:
    """`diffsim-3x3x3` cut to :data:`CODESIGN_UPDATES` updates; its kept design, the initial cube
    and 32 random designs of the distribution it starts from, all flown by its controller on the
    same 8 slews (float64, the mission's physics), scored by the objective."""
    from modsat_core.bench.codesign import initial_design, random_designs
    from modsat_core.spec.presets import get_preset
    from modsat_core.training.diffsim_codesign import score_designs

    d = get_preset("diffsim-3x3x3").model_dump(mode="json")
    steps = CODESIGN_UPDATES * 256 * 32
    d["seed"] = seed
    d["training"].update(total_env_steps=steps, eval_every_steps=steps, eval_episodes=8)
    d["evaluation"].update(episodes=16, trajectories=0, conditions=[])  # learning, not robustness
    files = train(JobSpec.model_validate(d)).artifacts()
    policy, kept, spec = load_policy(files["policy.pt"])
    assert kept is not None
    cube = initial_design(spec.design, spec.objective)
    rand = random_designs(spec.design, spec.objective, 32, seed)
    scores = score_designs(spec, policy.double(), [kept, cube, *rand], 8, spec.evaluation.seed + 2, exact=True)
    ev = json.loads(files["evaluation.json"])["policy"]["summary"]
    return {"kept": kept, "cube": cube, "scores": scores, "summary": ev}


@pytest.mark.slow
def test_codesign_moves_the_design_and_beats_what_chance_gives():
    """The kept design is not the initial cube; on the same slews and controller it scores better
    than the cube and than every one of 32 random designs from the distribution the run started
    from (a random design would be the best of 33 with probability 1/33); its own slews land."""
    out = codesign_outcome(0)
    kept_s, cube_s, rand_s = out["scores"][0], out["scores"][1], out["scores"][2:]
    assert not np.array_equal(out["kept"], out["cube"])
    assert kept_s < cube_s and kept_s < min(rand_s), (kept_s, cube_s, sorted(rand_s)[:3])
    assert out["summary"]["success_rate"] >= 0.95 and out["summary"]["safety_violations"] == 0, out["summary"]


# ----------------------------------------------------------------------------- the relaxed gradient


def test_a_relaxed_grid_has_the_grids_mass_properties_at_its_corners():
    rng = np.random.default_rng(0)
    grids = rng.integers(0, 3, size=(5, 3, 3, 3))
    grids[:, 1, 1, 1] = ACTUATOR
    occ = torch.as_tensor((grids > 0).reshape(5, -1), dtype=torch.float64)
    mass, com, inertia = mass_properties_of_occupancy(occ, 2.0, 0.1)
    for b, g in enumerate(grids):
        mp = mass_properties(g, 2.0, 0.1)
        assert float(mass[b]) == pytest.approx(mp.mass_kg)
        assert torch.allclose(com[b], torch.as_tensor(mp.com_grid_m), atol=1e-14)
        assert torch.allclose(inertia[b], torch.as_tensor(mp.inertia_B_kgm2), atol=1e-14)
    # half a module in an empty cell weighs half a module
    half = occ[:1].clone()
    cell = int(np.flatnonzero(occ[0].numpy() == 0)[0])
    half[0, cell] = 0.5
    whole = half.clone()
    whole[0, cell] = 1.0
    m0, m_half, m_whole = (float(mass_properties_of_occupancy(o, 2.0, 0.1)[0][0]) for o in (occ[:1], half, whole))
    assert m_half == pytest.approx(m0 + 1.0) and m_whole == pytest.approx(m0 + 2.0)


def test_a_weighted_wheel_slot_is_that_fraction_of_a_unit():
    """Two half-weighted slots fly exactly as one whole unit, and a weight of 1.0 as the unit's
    boolean slot: the relaxed grid's satellite is the discrete one at its corners."""
    spec = tiny_codesign()
    mission = spec.mission.model_copy(update={"episode_steps": 30})
    modules = spec.modules.model_copy(update={"momentum_capacity_Nms": 0.02})
    I_B = torch.diag(torch.tensor([0.3, 0.4, 0.5], dtype=torch.float64)).unsqueeze(0)
    rng = np.random.default_rng(3)
    draw = draw_episode(rng, mission)

    def fly(mask) -> torch.Tensor:
        sim = SlewSim(I_B, mask, mission, modules, dtype=torch.float64)
        sim.reset([0], [draw])
        pd = PDController(sim)
        for _ in range(30):
            sim.step(pd(sim))
        return torch.cat((sim.state.q_BN, sim.state.omega_B, sim.state.h_B.sum(1)), dim=-1)

    whole = fly(np.array([[True]]))
    assert torch.equal(fly(torch.tensor([[1.0]], dtype=torch.float64)), whole)
    assert torch.allclose(fly(torch.tensor([[0.5, 0.5]], dtype=torch.float64)), whole, atol=1e-12)

    # a quarter of a unit gives a quarter of the torque a full unit gives for the same command
    def first_torque(mask) -> torch.Tensor:
        sim = SlewSim(I_B, mask, mission, modules, dtype=torch.float64)
        sim.reset([0], [draw])
        return sim.step(torch.full((1, 1, 3), 0.5, dtype=torch.float64)).tau_c_B

    full = first_torque(np.array([[True]]))
    assert full.abs().min() > 0
    assert torch.allclose(first_torque(torch.tensor([[0.25]], dtype=torch.float64)), 0.25 * full, rtol=1e-12)


def test_the_relaxed_objectives_gradient_equals_finite_differences():
    spec = tiny_codesign(mission__episode_steps=16, diffsim__design_gradient="relaxed")
    run = DiffsimCodesignRun(spec)
    with torch.no_grad():
        run.logits.copy_(torch.as_tensor(np.random.default_rng(1).normal(0, 0.5, size=(8, 3))))
    J = run.relaxed_objective(seed=7)
    J.backward()
    grad = run.logits.grad.clone()
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0
    assert grad[torch.as_tensor(run.fixed.reshape(-1))].abs().max() == 0  # the payload's cells
    free = np.flatnonzero(~run.fixed.reshape(-1))
    eps = 1e-6
    for cell, kind in [(free[0], ACTUATOR), (free[1], STRUCTURE), (free[-1], EMPTY), (free[2], ACTUATOR)]:
        with torch.no_grad():
            run.logits[cell, kind] += eps
            up = float(run.relaxed_objective(seed=7))
            run.logits[cell, kind] -= 2 * eps
            down = float(run.relaxed_objective(seed=7))
            run.logits[cell, kind] += eps
        assert float(grad[cell, kind]) == pytest.approx((up - down) / (2 * eps), rel=1e-5, abs=1e-9)


def test_a_relaxed_run_moves_the_logits_by_its_gradient_and_resumes_the_same():
    spec = tiny_codesign(diffsim__design_gradient="relaxed")
    result = train(spec)
    files = result.artifacts()
    records = json.loads(files["curve.json"])["designs"]
    assert len(records) == 3 and all(r["relaxed_objective_s"] > 0 for r in records)
    assert is_valid(np.asarray(json.loads(files["design.json"])["grid"]))
    ckpts: list[dict] = []
    stops = iter([False, False, False, True])
    assert train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False)).stopped
    resumed = train(spec, checkpoint=checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1])))
    assert resumed.artifacts()["curve.json"] == files["curve.json"]
    # not the score function's run: the same draws, another step for the logits
    other = json.loads(train(tiny_codesign()).artifacts()["curve.json"])["designs"]
    assert [r["entropy_nats"] for r in other] != [r["entropy_nats"] for r in records]
