"""diffsim-control: the gradient through the simulator, the run's mechanics, its outputs and resume."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch

from modsat_core.agent.diffsim_policy import (
    DIFFSIM_NETWORK,
    N_DESIGN_INPUTS,
    N_DIFFSIM_INPUTS,
    DiffsimController,
    DiffsimPolicy,
    design_inputs,
    diffsim_inputs,
)
from modsat_core.agent.policy import controller_for
from modsat_core.agent.policy_file import load_policy
from modsat_core.grid import is_valid
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.pd import RATE_GAIN_MAX, RATE_GAIN_MAX_NO_DELAY_MARGIN, pd_gains
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec, SpecError, parse_spec
from modsat_core.spec.presets import get_preset
from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.diffsim import DiffsimRun, step_cost, training_mission, window_loss
from modsat_core.training.train import train

#: An asymmetric 2x2x2 design with two wheel units: products of inertia are not zero.
TWO_WHEELS = [[[2, 1], [1, 0]], [[0, 0], [2, 0]]]


def tiny_diffsim(**over) -> JobSpec:
    """A diffsim-control run that trains in a second or two (mechanics, not quality)."""
    d: dict = {
        "name": "tiny-diffsim",
        "algorithm": "diffsim-control",
        "seed": 5,
        "design": {"grid_size": 2, "fixed_design": TWO_WHEELS},
        "modules": {"torque_scale_Nm": 0.05, "actuator_model": "reaction-wheel", "momentum_capacity_Nms": 0.02},
        "mission": {"episode_steps": 24, "tolerance_deg": 1.0},
        "training": {"total_env_steps": 6 * 8 * 4, "eval_every_steps": 64, "eval_episodes": 3},
        "diffsim": {"batch_size": 8, "window_steps": 4, "episode_steps": 12, "substeps": 2, "hidden_sizes": [8]},
        "evaluation": {"episodes": 3, "trajectories": 1},
    }
    for key, value in over.items():
        section, _, field = key.partition("__")
        if field:
            d.setdefault(section, {})[field] = value
        else:
            d[section] = value
    return JobSpec.model_validate(d)


def _sim(spec: JobSpec, B: int, dtype=torch.float64) -> SlewSim:
    grid = np.asarray(spec.design.fixed_design)
    sim = SlewSim.from_designs(
        [Design.from_grid(grid, spec.modules)] * B,
        training_mission(spec.mission, spec.diffsim.substeps),
        spec.modules,
        dtype=dtype,
    )
    rng = np.random.default_rng(7)
    draws = [draw_episode(rng, spec.mission, {"omega_B": rng.normal(0, 0.05, 3)}) for _ in range(B)]
    sim.reset(list(range(B)), draws)
    return sim


@pytest.mark.parametrize("base", ["pd", "none"])
def test_the_window_gradient_equals_finite_differences(base):
    """The cost of a window, backpropagated through the controller (on the PD law or alone) and
    every RK4 step of the simulator (wheels at their momentum capacity included), against central
    differences in float64."""
    spec = tiny_diffsim(diffsim__window_steps=6, diffsim__base=base)
    torch.manual_seed(0)
    policy = DiffsimPolicy([8]).double()
    with torch.no_grad():  # weights large enough that the torque and the wheels' capacity matter
        for p in policy.parameters():
            p.mul_(0.0).add_(torch.randn_like(p) * 0.5)
    start = _sim(spec, 4)
    saved = start.flight_state()

    def loss() -> torch.Tensor:
        sim = _sim(spec, 4)
        sim.load_flight(saved)
        return window_loss(sim, DiffsimController(policy, spec.mission.rate_limit_rad_s, base), spec.diffsim)

    value = loss()
    value.backward()
    params = list(policy.parameters())
    checked = large = 0
    gen = torch.Generator().manual_seed(1)
    for p in params:
        for flat in torch.randperm(p.numel(), generator=gen)[:4].tolist():
            analytic = p.grad.reshape(-1)[flat].item()
            eps = 1e-6
            with torch.no_grad():
                p.reshape(-1)[flat] += eps
                up = loss().item()
                p.reshape(-1)[flat] -= 2 * eps
                down = loss().item()
                p.reshape(-1)[flat] += eps
            numeric = (up - down) / (2 * eps)
            # abs: the output layer's bias cancels in the odd output (its gradient is exactly 0;
            # the differences see float64 rounding of the cancellation, about 1e-7)
            assert analytic == pytest.approx(numeric, rel=1e-5, abs=1e-6), (p.shape, flat)
            checked += 1
            large += abs(analytic) > 1e-3
    assert checked >= 12 and large >= 8


def test_a_reset_between_steps_leaves_the_graph_intact_and_metrics_carry_none():
    """SlewSim replaces tensors on reset instead of writing them, and its episode metrics are
    detached: the learner can reset rows mid-flight and backpropagate what came before."""
    spec = tiny_diffsim()
    policy = DiffsimPolicy([8]).double()
    sim = _sim(spec, 3)
    ctrl = DiffsimController(policy, spec.mission.rate_limit_rad_s, "pd")
    sim.step(ctrl(sim))
    before = step_cost(sim, spec.diffsim).sum()
    sim.reset([1], [draw_episode(np.random.default_rng(3), spec.mission)])
    sim.step(ctrl(sim))
    (before + step_cost(sim, spec.diffsim).sum()).backward()
    assert all(not t.requires_grad for t in vars(sim.metrics).values())
    sim.detach()
    assert not sim.state.omega_B.requires_grad and not sim.state.q_BN.requires_grad


def test_the_controller_is_odd_and_zero_at_the_target():
    torch.manual_seed(0)
    policy = DiffsimPolicy([16, 16])
    with torch.no_grad():
        for p in policy.parameters():
            p.copy_(torch.randn_like(p))
    q = torch.nn.functional.normalize(torch.randn(5, 4), dim=-1)
    w, h = torch.randn(5, 3) * 0.1, torch.randn(5, 3) * 0.01
    box = torch.full((5, 1), 0.8)
    x = diffsim_inputs(q, w, h, 0.5, box)
    mirrored = diffsim_inputs(q * torch.tensor([1.0, -1, -1, -1]), -w, -h, 0.5, box)
    assert x.shape == (5, N_DIFFSIM_INPUTS)
    assert torch.allclose(policy(mirrored), -policy(x), atol=1e-6)
    rest = diffsim_inputs(torch.tensor([[1.0, 0, 0, 0]]), torch.zeros(1, 3), torch.zeros(1, 3), 0.5, box[:1])
    assert torch.equal(policy(rest), torch.zeros(1, 3))
    # the sign of the error quaternion does not matter: q and -q are one attitude
    assert torch.allclose(policy(diffsim_inputs(-q, w, h, 0.5, box)), policy(x))


@pytest.mark.parametrize("base", ["pd", "none"])
def test_a_run_writes_every_output_and_its_policy_file_reads_back(base):
    progress: list[dict] = []
    spec = tiny_diffsim(diffsim__base=base)
    result = train(spec, on_progress=progress.append)
    files = result.artifacts()
    assert not result.stopped and result.env_steps == 6 * 32
    exports = {"policy_export.pt", "policy_export.pt2", "policy_export.onnx"}  # tests/learning/test_export.py
    assert {"spec.json", "curve.json", "evaluation.json", "policy.pt", *exports} <= set(files)
    curve = json.loads(files["curve.json"])
    assert curve["algorithm"] == "diffsim-control"
    assert [p["env_steps"] for p in curve["points"]] == [64, 128, 192]
    assert all(p["grad_norm"] > 0 and np.isfinite(p["loss"]) for p in curve["points"])
    ev = json.loads(files["evaluation.json"])
    assert ev["policy"]["summary"]["episodes"] == 3 and ev["pd_baseline"]["summary"]["episodes"] == 3
    policy, grid, spec2 = load_policy(files["policy.pt"])
    assert isinstance(policy, DiffsimPolicy) and spec2 == spec
    assert np.array_equal(grid, np.asarray(TWO_WHEELS))
    # the standalone export gives the per-unit torque the controller commands in the simulator
    sim = _sim(spec, 6)
    with torch.no_grad():
        for _ in range(3):  # some wheel momentum, rates of every sign
            sim.step(torch.rand(6, 2, 3, dtype=torch.float64) * 2 - 1)
        expected = controller_for(policy, grid, spec2)(sim).clamp(-1, 1) * spec.modules.torque_scale_Nm
    exported = torch.jit.load(io.BytesIO(files["policy_export.pt"]))
    got = exported(sim.error_quaternion(), sim.state.omega_B, sim.state.h_B)
    assert got.shape == (6, 2, 3) and torch.allclose(got, expected, atol=1e-7)
    if base == "pd":  # the correction is not the whole torque: the PD law is in the export
        alone = DiffsimController(policy.double(), spec.mission.rate_limit_rad_s, "none")(sim)
        assert not torch.allclose(got, alone * spec.modules.torque_scale_Nm, atol=1e-4)
    steps = [p["env_steps"] for p in progress]
    assert steps == sorted(steps) and progress[-1]["phase"] == "evaluating"
    assert all("grad_norm" in p for p in progress if p["phase"] == "training")


def test_a_policy_file_from_before_the_pd_base_reads_as_the_network_alone():
    """`diffsim.base` came later: a policy file of network `diffsim-mlp` whose spec has no such key
    is the network alone, though the key's default is now `pd`."""
    spec = tiny_diffsim(diffsim__base="none")
    files = train(spec).artifacts()
    old = torch.load(io.BytesIO(files["policy.pt"]), weights_only=True)
    assert old["network"] == DIFFSIM_NETWORK
    del old["spec"]["diffsim"]["base"]
    buf = io.BytesIO()
    torch.save(old, buf)
    _policy, _grid, spec2 = load_policy(buf.getvalue())
    assert spec2.diffsim.base == "none"
    assert JobSpec.model_validate(old["spec"]).diffsim.base == "pd"  # the default a new spec gets


def test_a_policy_file_keeps_the_pd_cap_its_controller_was_trained_on():
    """PD's delay margin (`RATE_GAIN_MAX`) came later: a file records the cap; one without it flew
    the older cap, and its controller and export keep it."""
    spec = tiny_diffsim(modules={"torque_scale_Nm": 0.8, "actuator_model": "reaction-wheel"})
    files = train(spec).artifacts()
    new = torch.load(io.BytesIO(files["policy.pt"]), weights_only=True)
    assert new["pd_rate_gain_max"] == RATE_GAIN_MAX
    del new["pd_rate_gain_max"]
    buf = io.BytesIO()
    torch.save(new, buf)
    actor, grid, spec2 = load_policy(buf.getvalue())
    assert actor.pd_rate_gain_max == RATE_GAIN_MAX_NO_DELAY_MARGIN
    sim = SlewSim.from_designs([Design.from_grid(grid, spec2.modules)], spec2.mission, spec2.modules)
    gains = controller_for(actor, grid, spec2).gains(sim)
    # this design has the torque for the cap to bind: the two laws differ, and the old file keeps its own
    assert float(gains.c_per_s) * spec2.mission.control_dt_s == pytest.approx(RATE_GAIN_MAX_NO_DELAY_MARGIN)
    assert float(pd_gains(sim).c_per_s) * spec2.mission.control_dt_s == pytest.approx(RATE_GAIN_MAX)


def test_a_design_pool_flies_many_designs_and_the_controller_sees_each():
    """With `design_pool`, training rows fly the run's design or random valid ones, the network's
    inputs carry the design (even under the mirror: the output stays odd in the state), and the
    export bakes the run's design in."""
    spec = tiny_diffsim(diffsim__design_pool=5, diffsim__base="pd")
    run = DiffsimRun(spec)
    assert len(run.pool) == 6 and all(is_valid(d.grid) for d in run.pool)
    assert np.array_equal(run.pool[0].grid, np.asarray(TWO_WHEELS))
    assert run.policy.n_design == N_DESIGN_INPUTS
    before = run.sim.plant.I_B.clone()
    for _ in range(4):  # episodes of 12 steps, windows of 4: rows end and draw new designs
        run.update()
    assert len(set(run.row_design.tolist())) > 1
    for row, i in enumerate(run.row_design.tolist()):  # every row flies the design it drew
        assert torch.allclose(run.sim.plant.I_B[row].double(), torch.as_tensor(run.pool[i].I_B), rtol=1e-6)
        assert int(run.sim.plant.n_actuators[row]) == run.pool[i].n_actuators
    assert not torch.equal(before, run.sim.plant.I_B)
    # odd in the state for any design
    torch.manual_seed(0)
    q = torch.nn.functional.normalize(torch.randn(5, 4), dim=-1)
    w, h = torch.randn(5, 3) * 0.1, torch.randn(5, 3) * 0.01
    box = run.sim.plant.box_Nm[:5].float()
    design = design_inputs(run.sim.plant.I_B[:5].float(), box)
    x = torch.cat((diffsim_inputs(q, w, h, 0.5, box), design), dim=-1)
    xm = torch.cat((diffsim_inputs(q * torch.tensor([1.0, -1, -1, -1]), -w, -h, 0.5, box), design), dim=-1)
    with torch.no_grad():
        for p in run.policy.parameters():
            p.add_(torch.randn_like(p))
        assert torch.allclose(run.policy(xm), -run.policy(x), atol=1e-6)
    # outputs: the run's design is flown and exported with its own design inputs
    files = train(spec).artifacts()
    policy, grid, spec2 = load_policy(files["policy.pt"])
    assert isinstance(policy, DiffsimPolicy) and policy.n_design == N_DESIGN_INPUTS
    sim = _sim(spec, 4)
    with torch.no_grad():
        expected = controller_for(policy, grid, spec2)(sim).clamp(-1, 1) * spec.modules.torque_scale_Nm
    exported = torch.jit.load(io.BytesIO(files["policy_export.pt"]))
    assert torch.allclose(exported(sim.error_quaternion(), sim.state.omega_B, sim.state.h_B), expected, atol=1e-7)


def test_stop_and_resume_with_a_design_pool_gives_the_same_run():
    spec = tiny_diffsim(diffsim__design_pool=5)
    straight = train(spec)
    ckpts: list[dict] = []
    stops = iter([False, True])
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False))
    assert first.stopped
    resumed = train(spec, checkpoint=checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1])))
    assert resumed.curve == straight.curve
    assert straight.artifacts()["evaluation.json"] == resumed.artifacts()["evaluation.json"]


def test_stop_and_resume_gives_the_same_run():
    spec = tiny_diffsim()
    straight = train(spec)
    ckpts: list[dict] = []
    stops = iter([False, False, True])
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False))
    assert first.stopped and first.env_steps == 2 * 32
    ckpt = checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1]))  # as a file
    resumed = train(spec, checkpoint=ckpt)
    assert resumed.curve == straight.curve
    a, b = straight.artifacts(), resumed.artifacts()
    assert a["evaluation.json"] == b["evaluation.json"] and a["curve.json"] == b["curve.json"]


def test_the_budget_counts_control_steps_and_is_never_exceeded():
    run = DiffsimRun(tiny_diffsim(training__total_env_steps=100))  # 3 updates of 32; a 4th would overrun
    assert run.steps_per_update == 32
    assert run.run(lambda _p: None, lambda _c: None, lambda: False) is False
    assert run.env_steps == 96 and run.updates == 3 and run.curve[-1]["env_steps"] == 96
    assert run.lr(0) == pytest.approx(2e-3) and run.lr(2) == pytest.approx(1e-4)


def test_the_spec_asks_for_a_design_and_bounds_the_settings():
    with pytest.raises(SpecError, match=r"design\.fixed_design"):
        parse_spec({"algorithm": "diffsim-control"})
    with pytest.raises(SpecError, match=r"diffsim\.window_steps: 0 is out of range"):
        parse_spec({"algorithm": "diffsim-control", "diffsim": {"window_steps": 0}, "design": {"grid_size": 2}})
    with pytest.raises(SpecError, match="lr_final"):
        parse_spec({"diffsim": {"lr": 1e-4, "lr_final": 1e-3}})
    full = reference_design(3).tolist()
    assert parse_spec({"algorithm": "diffsim-control", "design": {"fixed_design": full}}).diffsim.window_steps == 32


#: The learning tests' budgets, in updates of 256 slews x 32 control steps (docs/diffsim.md has
#: the measurements behind them).
LANDS_UPDATES = 72
FASTER_UPDATES = 72


def paper_mission_run(base: str, updates: int, seed: int = 0) -> dict:
    """A diffsim-control run on the paper's 3x3x3 mission (the `cpu-3x3x3` preset's: 30-150 deg
    slews, 0.25 deg, rate under 0.01 rad/s, never over 0.5 rad/s), the full cube with its centre
    actuator; its evaluation.json: 64 held-out slews flown in float64 on the mission's own
    physics, by the policy and by PD."""
    d = get_preset("cpu-3x3x3").model_dump(mode="json")
    d.update(algorithm="diffsim-control", seed=seed)
    d["design"]["fixed_design"] = reference_design(3).tolist()
    d["diffsim"]["base"] = base
    steps = updates * 256 * 32
    d["training"].update(total_env_steps=steps, eval_every_steps=steps, eval_episodes=8, select_top_k=1)
    d["evaluation"].update(episodes=64, trajectories=0, conditions=[])  # learning, not robustness
    return json.loads(train(JobSpec.model_validate(d)).artifacts()["evaluation.json"])


@pytest.mark.slow
def test_the_network_alone_learns_to_land_the_paper_mission():
    """From scratch (`base` none): at least 95 % of 64 held-out slews land, none over the rate
    limit. A measured outcome on every seed tried (docs/diffsim.md), not one CPU's draw."""
    summary = paper_mission_run("none", LANDS_UPDATES)["policy"]["summary"]
    assert summary["success_rate_at_0.25_deg"] >= 0.95, summary
    assert summary["safety_violations"] == 0, summary


@pytest.mark.slow
def test_on_the_pd_law_it_lands_every_slew_sooner_than_pd():
    """On PD's law (`base` pd, the default), training starts from PD's slews (the correction starts
    near zero) and must make them faster: at least 95 % land, none over the rate limit, and the
    median settling time at most 0.92 of PD's on the same slews (measured 0.858-0.865 on seeds 0-4;
    PD itself is 1.0 by construction)."""
    ev = paper_mission_run("pd", FASTER_UPDATES)
    summary, pd = ev["policy"]["summary"], ev["pd_baseline"]["summary"]
    assert summary["success_rate_at_0.25_deg"] >= 0.95, summary
    assert summary["safety_violations"] == 0, summary
    assert summary["median_settling_time_s"] <= 0.92 * pd["median_settling_time_s"], (summary, pd)


def test_domain_randomisation_changes_training_and_resumes_exactly():
    """`randomise`: each training slew under conditions drawn for it (the true inertia in the sim, the
    design's in the controller; noise, delay, weak wheels, tumble, disturbance). Stop + resume is the
    straight run; the curve and final evaluation fly the nominal slews and the spec's conditions."""
    randomise = {
        "attitude_noise_deg": 0.01,
        "rate_noise_rad_s": 5e-4,
        "delay_steps": 2,
        "inertia_scale": 1.1,
        "inertia_rotation_deg": 5.0,
        "torque_fraction": 0.8,
        "tumble_rad_s": 0.05,
        "disturbance_Nm": 1e-4,
    }
    spec = tiny_diffsim(randomise=randomise, diffsim__design_pool=3)
    run = DiffsimRun(spec)
    f = run.flight
    assert f.noisy and f.history.shape[0] == 2 and f.I_model is not None
    assert not torch.allclose(f.I_model, run.sim.plant.I_B.to(f.I_model.dtype))  # the sim flies the true one
    straight = train(spec)
    assert straight.curve != train(tiny_diffsim(diffsim__design_pool=3)).curve
    ckpts: list[dict] = []
    stops = iter([False, True])
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: next(stops, False))
    assert first.stopped
    resumed = train(spec, checkpoint=checkpoint_from_bytes(checkpoint_to_bytes(ckpts[-1])))
    assert resumed.curve == straight.curve
    a, b = straight.artifacts(), resumed.artifacts()
    assert a["evaluation.json"] == b["evaluation.json"]
    ev = json.loads(a["evaluation.json"])
    assert [c["name"] for c in ev["conditions"]] == [c.name for c in spec.evaluation.conditions]
