"""TD3 under delay (docs/robustness.md, "TD3 under delay"): the policy observes its last command
(`training.observe_last_command`) in the replay, in every flight of the evaluation and in the exports,
and `randomise` starts once the curve has landed `training.randomise_after_success` of its slews."""

from __future__ import annotations

import io

import numpy as np
import onnxruntime as ort
import pytest
import torch

from modsat_core.agent.export import INPUT_NAMES, LAST_COMMAND_INPUT, export_files
from modsat_core.agent.networks import NETWORKS, make_actor, observes_last_command
from modsat_core.agent.onnx_meta import read_metadata
from modsat_core.agent.policy import PolicyController
from modsat_core.agent.policy_file import load_policy, n_features_of
from modsat_core.codesign.features import N_FEATURES, N_LAST_COMMAND
from modsat_core.codesign.mdp import Compact, observe_compact
from modsat_core.evaluation.monte_carlo import episode_rngs
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.evaluation import STANDARD_CONDITIONS
from modsat_core.spec.limits import replay_layout
from modsat_core.spec.presets import PRESETS
from modsat_core.training import td3_trainer
from modsat_core.training.td3_trainer import TD3Run
from modsat_core.training.train import train
from modsat_core.verify.run import ExportedPolicy, takes_last_command

from .conftest import tiny_spec
from .test_diffsim import TWO_WHEELS

RANDOMISE = STANDARD_CONDITIONS["combined"].changes()


def _control(**over):
    """A tiny `td3-control` run on two wheel units: every row flies from its first step."""
    return tiny_spec(
        algorithm="td3-control",
        design={"grid_size": 2, "design_steps": 3, "fixed_design": TWO_WHEELS},
        training__observe_last_command=True,
        **over,
    )


# ----------------------------------------------------------------------------- the spec


def test_old_specs_do_not_observe_it_and_the_td3_presets_do():
    old = tiny_spec()
    assert not old.training.observe_last_command and old.training.randomise_after_success is None
    assert n_features_of(old.training) == N_FEATURES
    assert replay_layout(2) == replay_layout(2, old.training.observe_last_command)  # the layout of before
    run = TD3Run(old)
    assert run.env.compact().last_cmd is None and "obs_last_cmd" not in run.buffer.data
    assert not observes_last_command(run.agent.actor)
    for name, spec in PRESETS.items():
        td3 = spec.algorithm in ("td3-codesign", "td3-control", "ga")
        assert spec.training.observe_last_command == td3, name
        assert (spec.training.randomise_after_success is not None) == td3, name


# ----------------------------------------------------------------------------- the replay


def test_a_stored_transition_observes_the_previous_action():
    run = TD3Run(_control())
    B, N, D = run.env.B, run.env.N, run.env.D
    actions = []
    for _ in range(5):
        before = run.buffer.size
        run.step()
        actions.append(run.buffer.data["action"][before : before + B].float().clone())
    data = run.buffer.data
    last = data["obs_last_cmd"][: 5 * B].float().reshape(5, B, -1, 3)
    assert last[0].abs().sum() == 0  # a flight's first step: no command yet
    ended = data["terminal"][: 5 * B].reshape(5, B)  # a safety violation ends a flight (12 steps: no time limit)
    for k in range(1, 5):
        go_on = ~ended[k - 1]
        torch.testing.assert_close(last[k][go_on], actions[k - 1][go_on])
        assert last[k][~go_on].abs().sum() == 0  # a new flight
    assert actions[0].abs().sum() > 0 and int((~ended[:4]).sum()) > 2 * B
    # The features the update rebuilds hold it: each wheel unit its own, every module the mean.
    row = {k[4:]: v[B : 2 * B] for k, v in data.items() if k.startswith("obs_")}
    obs = observe_compact(Compact.from_dict(row, last_cmd=row["last_cmd"]), N, D, run.spec.mission.rate_limit_rad_s)
    assert obs.x.shape[-1] == N_FEATURES + N_LAST_COMMAND
    units = obs.act_mask[0]
    own, mean = obs.x[:, :, N_FEATURES : N_FEATURES + 3], obs.x[:, :, N_FEATURES + 3 :]
    torch.testing.assert_close(own[:, units], last[1][:, units])
    torch.testing.assert_close(mean[:, 0], last[1][:, units].mean(dim=1))
    assert own[:, ~units].abs().sum() == 0


def test_a_flight_after_its_design_phase_starts_with_no_command():
    run = TD3Run(tiny_spec(design__repair=True, training__observe_last_command=True))
    D = run.env.D
    for _ in range(D + 3):
        run.step()
    data, B = run.buffer.data, run.env.B
    step = data["obs_design_step"][: run.buffer.size].long().reshape(-1, B)
    designing = step < D
    first = torch.zeros_like(designing)
    first[1:] = step[:-1] == D - 1  # a flight's first step follows the design's last
    assert designing.any() and first.any()
    last = data["obs_last_cmd"][: run.buffer.size].float().reshape(step.shape[0], B, -1)
    assert last[designing | first].abs().sum() == 0
    assert last[~(designing | first)].abs().sum() > 0


# ----------------------------------------------------------------------------- flying it


def _flown_sim(spec, grid, n=8, steps=4):
    sim = SlewSim.from_designs([Design.from_grid(grid, spec.modules)] * n, spec.mission, spec.modules)
    sim.reset(list(range(n)), [draw_episode(r, spec.mission) for r in episode_rngs(1, n)])
    gen = torch.Generator().manual_seed(0)
    K = int((np.asarray(grid) >= 2).sum())
    for _ in range(steps):
        sim.step(torch.rand((n, K, 3), generator=gen) * 2 - 1)
    return sim


@pytest.mark.parametrize("odd_control", [False, True])
@pytest.mark.parametrize("network", NETWORKS)
def test_the_exports_take_the_last_command_and_match_the_policy(network, odd_control):
    spec = tiny_spec(design={"grid_size": 3}, training__observe_last_command=True)
    grid = np.ones((3, 3, 3), dtype=np.int64)
    grid[0, 1, 1] = grid[1, 1, 1] = grid[2, 0, 2] = 2
    torch.manual_seed(0)
    actor = make_actor(network, N_FEATURES + N_LAST_COMMAND, [32, 32], odd_control, N_LAST_COMMAND).eval()
    tau = spec.modules.torque_scale_Nm
    sim = _flown_sim(spec, grid)
    ctrl = PolicyController(actor, grid, spec.design, spec.mission)
    first = ctrl(sim)  # the previous step's command, then this step's given it
    sim.step(first)
    expected = ctrl(sim) * tau
    assert not torch.allclose(expected, PolicyController(actor, grid, spec.design, spec.mission)(sim) * tau)
    files = export_files(actor, grid, spec)
    inputs = (sim.error_quaternion(), sim.state.omega_B, sim.state.h_B, first * tau)
    inputs = tuple(t.float() for t in inputs)
    with torch.no_grad():
        script = torch.jit.load(io.BytesIO(files["policy_export.pt"]))
        got = {
            "pt": script(*inputs),
            "pt2": torch.export.load(io.BytesIO(files["policy_export.pt2"])).module()(*inputs),
        }
    session = ort.InferenceSession(files["policy_export.onnx"], providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    assert names == [*INPUT_NAMES, LAST_COMMAND_INPUT]
    (onnx_tau,) = session.run(None, {name: t.numpy() for name, t in zip(names, inputs)})
    got["onnx"] = torch.from_numpy(onnx_tau)
    for name, t in got.items():
        torch.testing.assert_close(t, expected.float(), atol=1e-5, rtol=1e-5, msg=name)
    assert takes_last_command(script)
    assert LAST_COMMAND_INPUT in read_metadata(files["policy_export.onnx"])["modsat.inputs"]


def test_a_run_s_export_flies_as_its_policy_with_its_own_last_command():
    """`modsat verify`'s controller (the TorchScript export, fed its own previous output) and the
    evaluation's (the policy, fed its own) command the same torques step after step."""
    files = train(_control()).artifacts()
    actor, grid, spec = load_policy(files["policy.pt"])
    assert observes_last_command(actor)
    script = torch.jit.load(io.BytesIO(files["policy_export.pt"]))
    tau = spec.modules.torque_scale_Nm
    base = _flown_sim(spec, grid, steps=0)
    ours, theirs = PolicyController(actor, grid, spec.design, spec.mission), ExportedPolicy(script, tau)
    moved = False
    for _ in range(6):
        a, b = ours(base), theirs(base)
        torch.testing.assert_close(a.float(), b.float(), atol=1e-5, rtol=1e-5)
        moved |= bool(a.abs().sum() > 0)
        base.step(a)
    assert moved


def test_a_new_slew_starts_with_no_command():
    """One controller flies Monte-Carlo sets one after another: a row that has not stepped gets none."""
    spec = _control()
    grid = np.asarray(TWO_WHEELS)
    torch.manual_seed(0)
    actor = make_actor("per-module", N_FEATURES + N_LAST_COMMAND, [16, 16], False, N_LAST_COMMAND).eval()
    ctrl = PolicyController(actor, grid, spec.design, spec.mission)
    sim = _flown_sim(spec, grid, steps=0)
    first = ctrl(sim)
    sim.step(first)
    ctrl(sim)
    fresh = _flown_sim(spec, grid, steps=0)
    torch.testing.assert_close(ctrl(fresh), first)


# ----------------------------------------------------------------------------- the curriculum


def _points(monkeypatch, rates):
    """curve_point replaced: the curve's evaluations land ``rates`` in turn."""
    it = iter(rates)

    def fake(actor, grid, spec, env_steps, updates, penalty):
        return {"env_steps": env_steps, "updates": updates, "mean_return": 0.0, "success_rate": next(it)}

    monkeypatch.setattr(td3_trainer, "curve_point", fake)


def test_randomisation_starts_only_once_the_curve_lands_the_share(monkeypatch):
    spec = _control(randomise=RANDOMISE, training__randomise_after_success=0.5)
    _points(monkeypatch, [0.0, 0.25, 0.5, 0.0])
    run = TD3Run(spec)
    assert not run.env.randomising
    for _ in range(2):
        run.step()
        run.evaluate_now()
        assert not run.env.randomising
    # nominal flights so far: nothing drawn, no condition on any row
    assert run.env.flight.I_model is None and int(run.env.flight.delay.sum()) == 0
    run.step()
    run.evaluate_now()  # 0.5: the switch
    assert run.env.randomising
    assert all(not s["randomised"] for s in run.kept)
    for _ in range(run.spec.mission.episode_steps):  # every flight ends and a new one starts
        run.step()
    assert run.env.flight.I_model is not None  # new flights fly drawn conditions
    run.evaluate_now()  # a lower rate stays switched on; the snapshots from before are dropped
    assert run.env.randomising
    assert [s["randomised"] for s in run.kept] == [True]
    # a resumed run keeps the switch (read from the curve)
    again = TD3Run(spec)
    assert not again.env.randomising
    again.load_state_dict(run.state_dict())
    assert again.env.randomising


def test_without_randomise_the_gate_does_nothing_and_without_a_gate_it_starts_at_once(monkeypatch):
    _points(monkeypatch, [1.0])
    run = TD3Run(_control(training__randomise_after_success=0.5))
    run.step()
    run.evaluate_now()
    assert not run.env.randomising and run.kept[0]["randomised"] is False
    assert TD3Run(_control(randomise=RANDOMISE)).env.randomising


def test_a_run_with_both_trains_and_resumes_exactly(monkeypatch):
    """The switch, made by the curve at 320 env steps, is where a straight run and one resumed from
    before it (checkpoint at 160) both make it: the same curve."""
    from .conftest import first_checkpoint

    real = td3_trainer.curve_point

    def landing_from_320(actor, grid, spec, env_steps, updates, penalty):
        return {**real(actor, grid, spec, env_steps, updates, penalty), "success_rate": float(env_steps >= 320)}

    monkeypatch.setattr(td3_trainer, "curve_point", landing_from_320)
    spec = tiny_spec(
        design__repair=True,
        randomise=RANDOMISE,
        training__observe_last_command=True,
        training__randomise_after_success=0.5,
    )
    straight = train(spec)
    nominal = train(spec.model_copy(update={"randomise": spec.randomise.model_copy(update={"enabled": False})}))
    assert [p["mean_return"] for p in straight.curve[:2]] == [p["mean_return"] for p in nominal.curve[:2]]
    assert straight.curve != nominal.curve  # randomised after the switch
    ck = first_checkpoint(spec)
    assert ck["env_steps"] < 320
    assert train(spec, checkpoint=ck).curve == straight.curve


def test_the_flight_ready_cpu_example_is_the_preset_trained_for_the_flight_conditions():
    """docs/examples/cpu-3x3x3-flight-ready.json (the measurement of docs/robustness.md, "TD3 under
    delay") is `cpu-3x3x3` with `randomise` at the first-order presets' magnitudes, nothing else."""
    from pathlib import Path

    from modsat_core.spec.evaluation import FLIGHT_READY
    from modsat_core.spec.jobspec import JobSpec
    from modsat_core.spec.presets import get_preset

    path = Path(__file__).resolve().parents[2] / "docs" / "examples" / "cpu-3x3x3-flight-ready.json"
    example = JobSpec.model_validate_json(path.read_text())
    preset = get_preset("cpu-3x3x3")
    assert example.randomise.active and example.randomise == JobSpec(randomise=FLIGHT_READY).randomise
    assert example.model_copy(update={"name": preset.name, "randomise": preset.randomise}) == preset
