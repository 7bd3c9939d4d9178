"""Flight conditions change the simulation in the way each says (docs/robustness.md)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from modsat_core.evaluation.monte_carlo import monte_carlo, monte_carlo_conditions
from modsat_core.sim import quaternion as quat
from modsat_core.sim.conditions import Axes, Flight, RowConditions, true_inertia
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.pd import RATE_GAIN_MAX, PDController, pd_gains
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.evaluation import STANDARD_CONDITIONS, Condition, Randomise
from modsat_core.spec.jobspec import SpecError, parse_spec
from modsat_core.spec.presets import get_preset

SPEC = get_preset("cpu-3x3x3")
MISSION = SPEC.mission.model_copy(update={"episode_steps": 40, "gravity_gradient": False})
THREE = np.array(  # 3 wheel units off the centre, 16 modules: much torque for its inertia
    [[[2, 1, 0], [1, 1, 0], [0, 0, 0]], [[1, 1, 1], [1, 2, 1], [0, 1, 0]], [[0, 1, 0], [0, 1, 0], [0, 2, 0]]]
)


def _flight(B: int, rows: RowConditions, max_delay: int = 0, seed: int = 0) -> Flight:
    d = Design.from_grid(reference_design(3), SPEC.modules)
    sim = SlewSim.from_designs([d] * B, MISSION, SPEC.modules, dtype=torch.float64)
    rng = np.random.default_rng(0)
    sim.reset(list(range(B)), [draw_episode(rng, MISSION) for _ in range(B)])
    f = Flight(sim, max_delay=max_delay, seed=seed)
    f.set_rows(torch.arange(B), rows)
    return f


def _rows(B: int, **c) -> RowConditions:
    return RowConditions.of([Condition(**c)] * B)


def test_a_delay_of_one_step_shifts_the_action_sequence_by_one_step():
    f = _flight(3, RowConditions.of([Condition(), Condition(delay_steps=1), Condition(delay_steps=2)]), max_delay=2)
    commands = [torch.full((3, 1, 3), 0.1 * (k + 1), dtype=torch.float64) for k in range(5)]
    it = iter(commands)
    applied = [f.act(lambda _sim: next(it))[:, 0, 0].tolist() for _ in commands]
    cmd = [0.1 * (k + 1) for k in range(5)]
    assert [a[0] for a in applied] == pytest.approx(cmd)  # no delay: as commanded
    assert [a[1] for a in applied] == pytest.approx([0.0, *cmd[:-1]])  # one step late, nothing at first
    assert [a[2] for a in applied] == pytest.approx([0.0, 0.0, *cmd[:-2]])
    f.reset_rows(torch.tensor([1]))  # a new slew: nothing on its way to its wheels
    assert f.act(lambda _sim: commands[0])[1, 0, 0] == 0.0


def test_sensor_noise_has_the_stated_standard_deviation_and_the_truth_is_untouched():
    B, sig_att, sig_rate = 4000, 0.01, 5e-4
    f = _flight(B, _rows(B, attitude_noise_deg=sig_att, rate_noise_rad_s=sig_rate))
    truth_q, truth_w = f.sim.state.q_BN.clone(), f.sim.state.omega_B.clone()
    view = f.view()
    # the measured attitude is the true one turned by a small rotation: its rotation vector's std
    dq = quat.multiply(quat.conjugate(truth_q), view.state.q_BN)
    rotvec = 2.0 * dq[:, 1:] * torch.sign(dq[:, :1])
    assert rotvec.std(dim=0).numpy() / quat.DEG == pytest.approx([sig_att] * 3, rel=0.05)
    assert (view.state.omega_B - truth_w).std(dim=0).numpy() == pytest.approx([sig_rate] * 3, rel=0.05)
    assert torch.equal(f.sim.state.q_BN, truth_q) and torch.equal(f.sim.state.omega_B, truth_w)
    # the controller's error quaternion is the measured attitude's
    assert not torch.equal(view.error_quaternion(), f.sim.error_quaternion())
    # drawn afresh each step, and the same stream for the same seed
    again = _flight(B, _rows(B, attitude_noise_deg=sig_att, rate_noise_rad_s=sig_rate))
    assert torch.equal(again.view().state.omega_B, view.state.omega_B)
    assert not torch.equal(f.view().state.omega_B, view.state.omega_B)


def test_the_controller_knows_the_model_inertia_and_the_sim_flies_the_true_one():
    rows = _rows(2, inertia_scale=1.1, inertia_rotation_deg=5.0)
    I = np.stack([Design.from_grid(THREE, SPEC.modules).I_B] * 2)
    axes = Axes.draw(np.random.default_rng(1), 2)
    I_true = true_inertia(I, rows, axes)
    ev_model, V_model = np.linalg.eigh(I[0])
    ev_true, V_true = np.linalg.eigh(I_true[0])
    assert ev_true == pytest.approx(1.1 * ev_model)  # scaled
    # principal axes turned by 5 deg about the drawn axis: V_true = R V_model
    R = quat.to_matrix(torch.from_numpy(quat.axis_angle_np(axes.inertia[0], np.array(5.0 * quat.DEG)))).numpy()
    assert np.abs(np.abs(np.diag(V_true.T @ R @ V_model)) - 1.0).max() < 1e-9
    sim = SlewSim(
        torch.as_tensor(I_true), torch.ones(2, 3, dtype=torch.bool), MISSION, SPEC.modules, dtype=torch.float64
    )
    f = Flight(sim)
    f.set_rows(torch.arange(2), rows, torch.as_tensor(I))
    assert torch.allclose(f.view().plant.I_B, torch.as_tensor(I)) and torch.allclose(
        sim.plant.I_B, torch.as_tensor(I_true)
    )
    # PD's gains come from what the controller knows
    assert torch.equal(PDController(f.view()).gains.lam_per_s, pd_gains(f.view()).lam_per_s)


def test_weak_wheels_deliver_the_fraction_of_the_clipped_command():
    f = _flight(2, RowConditions.of([Condition(torque_fraction=0.8), Condition()]))
    a = f.act(lambda _sim: torch.tensor([[[2.0, -0.5, 0.25]], [[2.0, -0.5, 0.25]]], dtype=torch.float64))
    assert a[0, 0].tolist() == pytest.approx([0.8, -0.4, 0.2])
    assert a[1, 0].tolist() == pytest.approx([1.0, -0.5, 0.25])  # the sim clips the nominal row itself


def test_tumble_disturbance_and_slew_range_change_the_draws_and_nominal_changes_nothing():
    d = Design.from_grid(reference_design(3), SPEC.modules)
    conds = [
        Condition(name="still"),
        Condition(name="tumble", tumble_rad_s=0.05),
        Condition(name="push", disturbance_Nm=1e-3),
        Condition(name="wide", slew_min_deg=150.0, slew_max_deg=180.0),
    ]

    def hold(sim):  # no control: the draws show in the final state
        return torch.zeros(sim.B, sim.K, 3, dtype=sim.dtype)

    res = monte_carlo_conditions(d, hold, MISSION, SPEC.modules, conds, episodes=6, seed=3)
    assert list(res) == ["still", "tumble", "push", "wide"]
    plain = monte_carlo(d, hold, MISSION, SPEC.modules, episodes=6, seed=3)
    assert res["still"].episodes == plain.episodes  # the nominal condition is the evaluation's own flight
    assert res["tumble"].episodes[0]["slew_angle_deg"] == pytest.approx(plain.episodes[0]["slew_angle_deg"])
    angles = [e["slew_angle_deg"] for e in res["wide"].episodes]
    assert min(angles) >= 150.0 and max(angles) <= 180.0
    assert all(e["final_rate_rad_s"] > 0.04 for e in res["tumble"].episodes)  # still turning: no control
    assert all(e["final_rate_rad_s"] < 1e-9 for e in res["still"].episodes)
    assert all(e["final_rate_rad_s"] > 1e-4 for e in res["push"].episodes)  # a torque spun it up


def test_the_policy_and_pd_fly_the_same_draws_and_noise():
    """A controller built on the sim (PD, a class) and one that is a function (the policy) see the same
    measured states at every step, and the same run twice gives the same episodes."""
    d = Design.from_grid(reference_design(3), SPEC.modules)
    conds = [STANDARD_CONDITIONS["combined"]]
    seen: dict[str, list] = {"built": [], "function": []}

    class Built:
        def __init__(self, sim):
            pass

        def __call__(self, sim):
            seen["built"].append((sim.state.q_BN.clone(), sim.state.omega_B.clone()))
            return torch.zeros(sim.B, sim.K, 3, dtype=sim.dtype)

    def function(sim):
        seen["function"].append((sim.state.q_BN.clone(), sim.state.omega_B.clone()))
        return torch.zeros(sim.B, sim.K, 3, dtype=sim.dtype)

    monte_carlo_conditions(d, Built, MISSION, SPEC.modules, conds, episodes=4, seed=9)
    monte_carlo_conditions(d, function, MISSION, SPEC.modules, conds, episodes=4, seed=9)
    assert len(seen["built"]) == len(seen["function"]) == MISSION.episode_steps
    for (qa, wa), (qb, wb) in zip(seen["built"], seen["function"]):
        assert torch.equal(qa, qb) and torch.equal(wa, wb)
    a = monte_carlo_conditions(d, PDController, MISSION, SPEC.modules, conds, episodes=4, seed=9)
    b = monte_carlo_conditions(d, PDController, MISSION, SPEC.modules, conds, episodes=4, seed=9)
    assert a["combined"].episodes == b["combined"].episodes


def test_pd_keeps_a_delay_margin_on_a_design_with_much_torque():
    """One control step of delay: with the stated cap PD stays inside the rate limit where the older
    cap (c T = 1) broke it on every slew (docs/robustness.md)."""
    d = Design.from_grid(THREE, SPEC.modules)
    m = SPEC.mission.model_copy(update={"episode_steps": 120})
    sim = SlewSim.from_designs([d], m, SPEC.modules)
    assert float(pd_gains(sim).c_per_s) * m.control_dt_s == pytest.approx(RATE_GAIN_MAX)  # the cap binds here
    delay = [STANDARD_CONDITIONS["delay-1"]]
    res = monte_carlo_conditions(d, PDController, m, SPEC.modules, delay, episodes=8, seed=12345)
    assert res["delay-1"].summary()["safety_violations"] == 0

    class Older(PDController):
        def __init__(self, sim):
            self.gains = pd_gains(sim, rate_gain_max=1.0)

    old = monte_carlo_conditions(d, Older, m, SPEC.modules, delay, episodes=8, seed=12345)
    assert old["delay-1"].summary()["safety_violations"] == 8


def test_the_spec_names_standard_conditions_and_rejects_bad_ones():
    d = SPEC.model_dump(mode="json")
    d["evaluation"]["conditions"] = ["delay-1", {"name": "late-2", "delay_steps": 2}]
    spec = parse_spec(d)
    assert [c.name for c in spec.evaluation.conditions] == ["delay-1", "late-2"]
    assert spec.evaluation.conditions[1].changes() == {"delay_steps": 2}
    assert [c.name for c in SPEC.evaluation.conditions] == list(STANDARD_CONDITIONS)
    for bad, words in (
        (["nope"], "unknown condition 'nope'"),
        (["delay-1", "delay-1"], "repeated: delay-1"),
        ([{"name": "nominal"}], "'nominal' names"),
        ([{"name": "x", "delay_steps": 11}], "delay_steps"),
        ([{"name": "x", "slew_min_deg": 40, "slew_max_deg": 30}], "must not exceed"),
        # not objects: a message naming the item, not a crash (they were 500s at the API)
        ([True], r"conditions\.0: Input should be an object"),
        ([[1]], r"conditions\.0: Input should be an object"),
        ([1.5], r"conditions\.0: Input should be an object"),
        ([[None, None]], r"conditions\.0: Input should be an object"),
    ):
        d["evaluation"]["conditions"] = bad
        with pytest.raises(SpecError, match=words):
            parse_spec(d)
    assert not Randomise().active and Randomise(delay_steps=1).active
    assert not Randomise(delay_steps=1, enabled=False).active  # a preset's randomisation turned off


def test_randomised_rows_stay_inside_their_ranges():
    r = Randomise(attitude_noise_deg=0.01, delay_steps=2, inertia_scale=1.2, torque_fraction=0.7, tumble_rad_s=0.1)
    rows = RowConditions.drawn(r, np.random.default_rng(0), 2000)
    assert set(np.unique(rows.delay_steps)) == {0, 1, 2}
    assert rows.inertia_scale.min() >= 1 / 1.2 - 1e-12 and rows.inertia_scale.max() <= 1.2
    assert rows.inertia_scale.min() < 0.9 and rows.inertia_scale.max() > 1.1  # either side of the model
    assert rows.torque_fraction.min() >= 0.7 and rows.torque_fraction.max() <= 1.0
    assert 0 <= rows.tumble_rad_s.min() and rows.tumble_rad_s.max() <= 0.1
    assert rows.disturbance_Nm.max() == 0.0 and rows.inertia_rotation_rad.max() == 0.0


def test_slots_grown_mid_flight_are_empty_and_change_nothing_of_the_flight():
    """A design learner's simulator grows its wheel-unit slots when a draw carries more units: the flights
    under way (their wheels' momentum, the commands on their way under a delay) go on as before."""
    modules = get_preset("trade-off-3x3x3").modules
    grid = np.where(THREE == 2, np.array([2, 3, 2])[None, None, :].repeat(3, 0).repeat(3, 1), THREE)
    d = Design.from_grid(grid, modules)
    rows = RowConditions.of([Condition(delay_steps=1), Condition()])

    def fly(grow_at: int | None) -> Flight:
        sim = SlewSim.from_designs([d, d], MISSION, modules, dtype=torch.float64)
        rng = np.random.default_rng(4)
        sim.reset([0, 1], [draw_episode(rng, MISSION) for _ in range(2)])
        f = Flight(sim, max_delay=1)
        f.set_rows(torch.arange(2), rows)
        pd = PDController(sim)
        for k in range(30):
            if k == grow_at:
                f.grow_slots(sim.K + 7)
                assert sim.K == d.n_actuators + 7 and f.history.shape == (1, 2, sim.K, 3)
                assert not sim.plant.slots[:, d.n_actuators :].any() and not sim.state.h_B[:, d.n_actuators :].any()
            f.step(pd)
        return f

    a, b = fly(None), fly(12)
    K = a.sim.K
    assert b.sim.K == K + 7 and not b.sim.state.h_B[:, K:].any()
    torch.testing.assert_close(b.sim.state.q_BN, a.sim.state.q_BN, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(b.sim.state.omega_B, a.sim.state.omega_B, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(b.sim.state.h_B[:, :K], a.sim.state.h_B, rtol=1e-12, atol=1e-12)
    assert a.sim.state.h_B.abs().sum() > 0  # the wheels did turn


@pytest.mark.slow  # compiles the RK4 step in float64 (inductor): a minute or more on a busy 2-core CPU
def test_a_compiled_evaluation_flies_the_conditions_as_the_eager_one():
    """``evaluation.compiled``: the same slews under the same conditions, PD flying the three-unit design
    (much torque for its inertia), give the same episodes to float64 rounding."""
    d = Design.from_grid(THREE, SPEC.modules)
    conds = [STANDARD_CONDITIONS[n] for n in ("delay-1", "weak-wheels", "combined")]
    kw = dict(episodes=5, seed=4, dtype=torch.float64)
    eager = monte_carlo_conditions(d, PDController, MISSION, SPEC.modules, conds, **kw)
    fused = monte_carlo_conditions(d, PDController, MISSION, SPEC.modules, conds, compiled=True, **kw)
    from modsat_core.sim import dynamics

    assert dynamics._COMPILED is not None  # the fused step was built and flown
    for c in conds:
        for e, f in zip(eager[c.name].episodes, fused[c.name].episodes, strict=True):
            assert f["success"] == e["success"] and f["safety_violation"] == e["safety_violation"]
            assert f["final_error_deg"] == pytest.approx(e["final_error_deg"], rel=1e-9, abs=1e-9)
            assert f["return"] == pytest.approx(e["return"], rel=1e-9)
