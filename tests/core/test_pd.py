"""PD baseline on the paper's 3x3x3 reference satellite: 100 seeded slews."""

import numpy as np

from modsat_core.evaluation.monte_carlo import monte_carlo
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design
from modsat_core.spec.presets import get_preset


def test_pd_flies_100_slews_within_quarter_degree_without_safety_violation():
    spec = get_preset("paper-3x3x3")  # 0.8 N m torque scale, 30-150 deg, 500 x 20 x 1/240 s
    design = Design.from_grid(reference_design(3), spec.modules)
    assert design.n_actuators == 1
    res = monte_carlo(design, PDController, spec.mission, spec.modules, episodes=100, seed=2024)
    s = res.summary()
    print(
        f"\nPD on the full 3x3x3 with centre actuator: success {s['success_rate']:.2%}, "
        f"median slew time / eigenaxis bound {s['median_slew_time_ratio']:.3f}, "
        f"median settling {s['median_settling_time_s']:.2f} s, peak rate {s['max_peak_rate_rad_s']:.3f} rad/s"
    )
    assert s["success_rate"] >= 0.99
    assert s["safety_violations"] == 0
    assert all(e["final_error_deg"] <= 0.25 for e in res.episodes if e["success"])
    angles = [e["slew_angle_deg"] for e in res.episodes]
    assert 30 <= min(angles) and max(angles) <= 150 and max(angles) - min(angles) > 100
    # Rate-limited eigenaxis slews cannot beat the time-optimal bound.
    assert min(e["slew_time_ratio"] for e in res.episodes) > 1.0
    assert 1.0 < s["median_slew_time_ratio"] < 3.0


def test_pd_works_with_wheels_and_an_asymmetric_multi_actuator_design():
    spec = get_preset("cpu-3x3x3")  # reaction-wheel model
    g = np.zeros((3, 3, 3), dtype=int)
    g[:, 1, 1] = 1
    g[1, :, 1] = 1
    g[0, 1, 1] = 2
    g[1, 2, 1] = 2
    g[2, 1, 0] = 1
    design = Design.from_grid(g, spec.modules)
    res = monte_carlo(design, PDController, spec.mission, spec.modules, episodes=20, seed=5, record=1)
    assert res.summary()["success_rate"] >= 0.95
    traj = res.trajectories[0]
    assert len(traj["t_s"]) == spec.mission.episode_steps + 1
    assert max(abs(np.asarray(traj["h_B"])).ravel()) > 0.01  # the wheels stored momentum
