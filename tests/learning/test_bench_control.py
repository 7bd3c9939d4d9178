"""`modsat bench control`: the flat-state TD3 diagnostic (mechanics, on a tiny budget)."""

from __future__ import annotations

import json

import numpy as np
import torch

from modsat_core.codesign.features import N_COMMON, N_DESIGN, PhysState, cell_observation
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.training.td3_control import bench_control, flat_state
from server.cli import main

from .conftest import tiny_spec


def test_flat_state_is_what_an_actuator_cell_sees(tiny):
    """The diagnostic's input is the control part of the co-design features of the actuator cell."""
    spec = tiny()
    grid = reference_design(2)
    sim = SlewSim.from_designs([Design.from_grid(grid, spec.modules)] * 3, spec.mission, spec.modules)
    sim.reset(
        [0, 1, 2],
        [draw_episode(np.random.default_rng(i), spec.mission, {"omega_B": [0.1, -0.2, 0.05]}) for i in range(3)],
    )
    sim.state.h_B[:] = torch.tensor([0.01, -0.02, 0.03])
    cell = int(np.flatnonzero(grid.reshape(-1) == 2)[0])
    h_cells = torch.zeros(3, 8, 3)
    h_cells[:, cell] = sim.state.h_B[:, 0] / sim.h_scale_Nms
    phys = PhysState(sim.state.q_BN, sim.q_TN, sim.state.omega_B, h_cells)
    obs = cell_observation(
        torch.as_tensor(grid).long().expand(3, 2, 2, 2), torch.full((3,), 3), 3, phys, spec.mission.rate_limit_rad_s
    )
    torch.testing.assert_close(flat_state(sim), obs.x[:, cell, N_COMMON + N_DESIGN :])


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
