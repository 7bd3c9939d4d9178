"""`training.hold_cone_start_deg`: a tolerance curriculum, rewards recomputed when replayed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from modsat_core.codesign.mdp import relabel_rows
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode, relabel
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.training.td3_control import bench_control
from modsat_core.training.td3_trainer import TD3Run
from modsat_core.training.train import train

from .conftest import first_checkpoint, tiny_spec


def _spec(episode_steps: int = 40, **over):
    mission = {
        "episode_steps": episode_steps,
        "tolerance_deg": 1.0,
        "reward": {
            "safety_penalty_per_remaining_step": 1.0,
            "no_progress_penalty_in_tolerance": False,
            "settle_bonus": 5.0,
        },
    }
    return tiny_spec(mission=mission, **over)


def test_the_cone_shrinks_geometrically_from_the_start_to_the_tolerance():
    t = _spec(training__hold_cone_start_deg=4.0).training  # learning starts at 96 of 480 steps
    assert t.hold_cone_deg(0, 1.0) == 4.0 and t.hold_cone_deg(96, 1.0) == 4.0
    assert math.isclose(t.hold_cone_deg(96 + 192, 1.0), 2.0)  # halfway: the geometric mean
    assert math.isclose(t.hold_cone_deg(480, 1.0), 1.0) and math.isclose(t.hold_cone_deg(10**6, 1.0), 1.0)
    short = _spec(training__hold_cone_start_deg=4.0, training__hold_cone_steps=96).training
    assert math.isclose(short.hold_cone_deg(96 + 48, 1.0), 2.0) and math.isclose(short.hold_cone_deg(300, 1.0), 1.0)
    assert _spec().training.hold_cone_deg(200, 1.0) == 1.0  # off by default


def test_bad_cones_are_refused_naming_the_field():
    with pytest.raises(ValidationError, match="hold_cone_start_deg"):
        _spec(training__hold_cone_start_deg=0.5)  # narrower than the 1 deg tolerance
    with pytest.raises(ValidationError, match="n_step"):
        _spec(training__hold_cone_start_deg=4.0, training__n_step=3)
    with pytest.raises(ValidationError, match="hold_cone_start_deg"):
        _spec(training__hold_cone_start_deg=-1.0)


def _pd_flights(spec, steps: int = 250):
    """PD flying the 2x2x2 reference design: transitions that end inside the tolerance."""
    design = Design.from_grid(reference_design(2), spec.modules)
    sim = SlewSim.from_designs([design] * 6, spec.mission, spec.modules, dtype=torch.float32)
    sim.reset(list(range(6)), [draw_episode(np.random.default_rng(i), spec.mission) for i in range(6)])
    pd = PDController(sim)
    rows = []
    for _ in range(steps):
        q, a = sim.error_quaternion(), pd(sim)
        out = sim.step(a)
        rows.append((out.reward, q, sim.error_quaternion(), sim.state.omega_B.clone(), out.terminated, out.phi_rad))
    return [torch.cat(x) for x in zip(*rows)]


def test_relabelling_with_the_mission_s_cone_gives_back_the_simulator_s_rewards():
    spec = _spec(episode_steps=400)
    r, q, q2, w2, term, phi = _pd_flights(spec)
    m = spec.mission
    assert bool((phi < math.radians(1.0)).any()) and bool((phi > math.radians(4.0)).any())
    # the same up to float32 rounding (the simulator's sums run in another order)
    torch.testing.assert_close(relabel(r, q, q2, w2, term, m, 1.0), r, rtol=0.0, atol=1e-6)
    wide = relabel(r, q, q2, w2, term, m, 4.0)
    between = (phi > math.radians(1.0)) & (phi <= math.radians(4.0)) & ~term
    assert bool(between.any())
    # between the tolerance and the wider cone the hold terms now pay; elsewhere nothing changed
    assert bool((wide[between] > r[between] + m.reward.in_tolerance_bonus - 1.5).all())
    torch.testing.assert_close(wide[~between], r[~between], rtol=0.0, atol=1e-6)
    # a violation keeps its stored penalty whatever the cone
    keep = torch.ones_like(term)
    assert torch.equal(relabel(r, q, q2, w2, keep, m, 4.0), r)


def test_a_replayed_co_design_batch_is_relabelled_on_its_flight_rows_only():
    spec = _spec(training__hold_cone_start_deg=4.0, design__repair=True)
    run = TD3Run(spec)
    run.run(lambda p: None, lambda ck: None, lambda: False, budget=200)
    b = run.buffer.sample(256, torch.Generator().manual_seed(0))
    D = run.env.D
    torch.testing.assert_close(
        relabel_rows(b, D, spec.mission, spec.mission.tolerance_deg), b["reward"], rtol=0.0, atol=1e-6
    )
    everywhere = relabel_rows(b, D, spec.mission, 180.0)  # every flight row inside the cone
    flight = (b["obs_design_step"] >= D) & ~b["terminal"]
    assert bool(flight.any()) and bool((~flight).any())
    assert bool((everywhere[flight] >= spec.mission.reward.in_tolerance_bonus).all())
    assert torch.equal(everywhere[~flight], b["reward"][~flight])


def test_runs_with_the_curriculum_resume_exactly_and_bench_control_uses_it():
    # a cone from 180 deg: the tiny runs' flights come nowhere near 1 deg, but they are in this one
    spec = _spec(training__hold_cone_start_deg=180.0, design__repair=True)
    full = train(spec)
    assert full.curve != train(_spec(design__repair=True)).curve  # the replayed rewards changed
    assert train(spec, checkpoint=first_checkpoint(spec)).curve == full.curve
    with_cone = bench_control(_spec(training__total_env_steps=400, training__hold_cone_start_deg=180.0), eval_every=400)
    assert with_cone["curve"] != bench_control(_spec(training__total_env_steps=400), eval_every=400)["curve"]
