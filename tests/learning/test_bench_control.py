"""`modsat bench control`: the flat-state TD3 diagnostic (mechanics, on a tiny budget)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from modsat_core.agent.flat_networks import FlatCellActor, FlatCellCritic, flat_observation
from modsat_core.agent.policy import PolicyController
from modsat_core.bench.control import bench_control
from modsat_core.codesign.features import control_globals
from modsat_core.grid import ACTUATOR
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.training.td3_trainer import TD3Run
from server.cli import main

from .conftest import tiny_spec


def flat_state(sim: SlewSim) -> torch.Tensor:
    """(B, 20 + 3K) the satellite's flat state read off the simulator: the control globals and
    each wheel unit's momentum (what the flat networks must see in per-cell observations)."""
    h = (sim.state.h_B / sim.h_scale_Nms).reshape(sim.B, -1)
    glob = control_globals(sim.error_quaternion(), sim.state.omega_B, sim.mission.rate_limit_rad_s)
    return torch.cat((glob, h), dim=-1).float()


def _two_actuators() -> np.ndarray:
    grid = reference_design(2)
    grid.reshape(-1)[2] = ACTUATOR  # and 7, the reference actuator
    return grid


def test_the_flat_networks_see_the_flat_state_and_act_on_the_actuator_cells(tiny):
    spec = tiny()
    grid = _two_actuators()
    sim = SlewSim.from_designs([Design.from_grid(grid, spec.modules)] * 3, spec.mission, spec.modules)
    sim.reset(
        [0, 1, 2],
        [draw_episode(np.random.default_rng(i), spec.mission, {"omega_B": [0.1, -0.2, 0.05]}) for i in range(3)],
    )
    sim.state.h_B[:] = 0.01 * torch.randn(3, 2, 3, generator=torch.Generator().manual_seed(0))
    # as the policy's Monte-Carlo sees it
    obs = PolicyController(None, grid, spec.design, spec.mission).observation(sim)
    cells = torch.as_tensor(np.flatnonzero(grid.reshape(-1) == ACTUATOR))
    torch.testing.assert_close(flat_observation(obs, cells), flat_state(sim))
    actor, critic = FlatCellActor(grid, [8, 8]), FlatCellCritic(grid, [8, 8])
    a = actor(obs)
    assert a.shape == (3, 8, 3) and not a[:, [c for c in range(8) if c not in cells.tolist()]].any()
    torch.testing.assert_close(a[:, cells], actor.mlp(flat_state(sim)).reshape(3, 2, 3))
    q1, q2 = critic(obs, a)
    ref1, ref2 = critic.mlp(flat_state(sim), a[:, cells].reshape(3, 6))
    torch.testing.assert_close((q1, q2), (ref1, ref2))


def test_the_trainer_trains_the_flat_networks_on_a_fixed_design():
    spec = tiny_spec(training__total_env_steps=400)
    with pytest.raises(ValueError, match="fixed design"):
        TD3Run(spec, flat=True)
    run = TD3Run(spec, fixed_grid=_two_actuators(), flat=True)
    assert isinstance(run.agent.actor, FlatCellActor) and isinstance(run.agent.critic, FlatCellCritic)
    before = [p.clone() for p in run.agent.actor.parameters()]
    while run.env_steps + run.env.B <= spec.training.total_env_steps:
        run.step()
    assert run.env_steps == 400 and run.agent.updates > 0 and run.buffer.size == 400
    assert any(not torch.equal(b, p) for b, p in zip(before, run.agent.actor.parameters()))


def test_bench_control_can_fly_the_target_actor():
    report = bench_control(tiny_spec(training__total_env_steps=400), eval_every=200, eval_target=True)
    assert [p["env_steps"] for p in report["curve"]] == [200, 400]
    for p in report["curve"]:
        assert set(p["target"]) <= set(p) and 0.0 <= p["target"]["success_rate"] <= 1.0
    # the target actor is a different network from the actor (a Polyak average), so its flights differ
    assert any(p["target"]["mean_return"] != p["mean_return"] for p in report["curve"])
    plain = bench_control(tiny_spec(training__total_env_steps=400), eval_every=200)
    assert "target" not in plain["curve"][0]


def test_cli_bench_control_trains_evaluates_and_compares_with_pd(tiny, tmp_path, capsys):
    spec_path = tmp_path / "tiny.json"
    spec_path.write_text(tiny().model_dump_json())
    out = tmp_path / "reports" / "control.json"
    assert (
        main(
            [
                "bench",
                "control",
                str(spec_path),
                "--steps",
                "400",
                "--eval-every",
                "200",
                "--hidden",
                "8",
                "8",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    report = json.loads(out.read_text())
    assert json.loads(capsys.readouterr().out) == report
    assert report["hidden_sizes"] == [8, 8] and report["env_steps"] <= 400 and report["updates"] > 0
    assert [p["env_steps"] for p in report["curve"]] == [200, 400]
    assert report["best"] in report["curve"]
    assert 0.0 <= report["pd_baseline"]["success_rate"] <= 1.0


def test_cli_bench_control_rejects_bad_sizes(tiny, tmp_path, capsys):
    spec_path = tmp_path / "tiny.json"
    spec_path.write_text(tiny().model_dump_json())
    assert main(["bench", "control", str(spec_path), "--hidden", "1"]) == 2
    assert "hidden_sizes" in capsys.readouterr().err
    # --out names the report file: a directory there fails before any training, not after it
    assert main(["bench", "control", str(spec_path), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "Is a directory" in err and str(tmp_path) in err


def test_the_flat_network_refuses_what_it_cannot_observe(tmp_path, capsys):
    """A TD3 preset's last command and curriculum: a readable refusal, not a run that ignores them."""
    spec = tiny_spec(training__observe_last_command=True)
    with pytest.raises(ValueError, match="observe_last_command"):
        TD3Run(spec, fixed_grid=reference_design(3), flat=True)
    path = tmp_path / "spec.json"
    path.write_text(tiny_spec(training__randomise_after_success=0.5).model_dump_json())
    with pytest.raises(SystemExit, match="randomise_after_success"):
        main(["bench", "control", str(path)])
