"""Gymnasium adapters: env checker, vector/single equivalence, reset options, info."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import modsat_core  # noqa: F401  (registers the env)
from modsat_core.sim.gym_envs import SatelliteSlewEnv, SatelliteSlewVectorEnv, reference_design

SHORT = {"mission": {"episode_steps": 25}}  # short episodes so the tests cross resets


def test_registered_env_passes_check_env():
    env = gym.make("modsat/SatelliteSlew-v0", spec=SHORT)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    for key in ("q_BN", "omega_B", "h_B", "error_deg", "q_TN"):
        assert key in info
    assert 30.0 <= info["error_deg"] <= 150.0


@pytest.mark.parametrize("model", ["ideal-torque", "reaction-wheel"])
def test_check_env_both_actuator_models_and_a_multi_actuator_design(model):
    g = np.ones((3, 3, 3), dtype=int)
    g[0, 0, 0] = g[2, 2, 2] = 2
    env = SatelliteSlewEnv(spec={**SHORT, "modules": {"actuator_model": model}}, design=g)
    assert env.action_space.shape == (2, 3)
    check_env(env, skip_render_check=True)


def test_vector_env_matches_single_envs_step_for_step():
    n, steps = 3, 60  # 60 steps of 25-step episodes: two autoresets per sub-env
    spec = {**SHORT, "mission": {"episode_steps": 25, "residual_torque_std_Nm": 1e-3}}
    venv = SatelliteSlewVectorEnv(n, spec=spec)
    envs = [SatelliteSlewEnv(spec=spec) for _ in range(n)]
    vobs, _ = venv.reset(seed=10)
    sobs = [e.reset(seed=10 + i)[0] for i, e in enumerate(envs)]
    np.testing.assert_array_equal(vobs, np.stack(sobs))
    rng = np.random.default_rng(0)
    need_reset = [False] * n
    for _ in range(steps):
        actions = rng.uniform(-1, 1, size=(n, 1, 3)).astype(np.float32)
        vobs, vrew, vterm, vtrunc, vinfo = venv.step(actions)
        for i, e in enumerate(envs):
            if need_reset[i]:
                obs, _ = e.reset()
                rew, term, trunc = 0.0, False, False
                need_reset[i] = False
            else:
                obs, rew, term, trunc, info = e.step(actions[i])
                need_reset[i] = term or trunc
                np.testing.assert_array_equal(vinfo["q_BN"][i], info["q_BN"])
            np.testing.assert_array_equal(vobs[i], obs)
            assert vrew[i] == rew and vterm[i] == term and vtrunc[i] == trunc
    assert venv.sim.steps.max() < 25  # episodes did restart


def test_reset_options_fix_initial_target_and_rate():
    env = SatelliteSlewEnv(spec=SHORT)
    q_TN = np.array([np.cos(0.5), 0.0, np.sin(0.5), 0.0])  # 57.3 deg about y
    q_BN = np.array([1.0, 0.0, 0.0, 0.0])
    _obs, info = env.reset(seed=1, options={"q_BN": q_BN, "q_TN": q_TN, "omega_B": [0.01, 0.0, 0.0]})
    np.testing.assert_allclose(info["q_TN"], q_TN)
    np.testing.assert_allclose(info["omega_B"], [0.01, 0.0, 0.0])
    assert info["error_deg"] == pytest.approx(np.degrees(1.0))
    with pytest.raises(ValueError, match="unit quaternion"):
        env.reset(options={"q_TN": [0.0, 0.0, 0.0, 0.0]})
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"target": [1, 0, 0, 0]})


def test_hold_at_target_earns_the_tolerance_bonus_and_a_spin_ends_with_the_safety_penalty():
    env = SatelliteSlewEnv(spec=SHORT)
    env.reset(seed=0, options={"q_TN": [1.0, 0, 0, 0]})
    _, r, term, trunc, info = env.step(np.zeros((1, 3), dtype=np.float32))
    assert r == pytest.approx(1.0 - 1.0 + 9.0)  # exp(0) - no progress (0 >= 0) + bonus
    env.reset(seed=0, options={"omega_B": [0.49, 0.0, 0.0]})
    _, r, term, trunc, info = env.step(np.array([[1.0, 0.0, 0.0]], dtype=np.float32))
    assert term and not trunc and r == -50.0
    assert info["episode"]["safety_violation"] and not info["episode"]["success"]


def test_settled_bonus_is_paid_only_below_the_rate_tolerance():
    """`bonus_needs_settled`: passing through the tolerance cone earns no bonus; holding still does."""
    spec = {**SHORT, "mission": {**SHORT["mission"], "reward": {"bonus_needs_settled": True}}}
    env = SatelliteSlewEnv(spec=spec)
    env.reset(seed=0, options={"q_TN": [1.0, 0, 0, 0]})
    _, r, *_ = env.step(np.zeros((1, 3), dtype=np.float32))
    assert r == pytest.approx(1.0 - 1.0 + 9.0)  # at rest on target: settled
    env.reset(seed=0, options={"q_TN": [1.0, 0, 0, 0], "omega_B": [0.02, 0.0, 0.0]})
    _, r, *_, info = env.step(np.zeros((1, 3), dtype=np.float32))
    assert info["error_deg"] < 1.0 and r == pytest.approx(
        np.exp(-np.radians(info["error_deg"]) / (0.28 * np.pi)) - 1.0, rel=1e-4
    )


def test_hold_reward_without_in_cone_progress_penalty_and_with_settle_bonus():
    """A satellite held still on target pays no progress penalty, and earns the settle bonus in full;
    a moving one inside the cone earns less of it."""
    reward = {"no_progress_penalty_in_tolerance": False, "settle_bonus": 5.0, "settle_rate_scale_rad_s": 0.05}
    env = SatelliteSlewEnv(spec={**SHORT, "mission": {**SHORT["mission"], "reward": reward}})
    env.reset(seed=0, options={"q_TN": [1.0, 0, 0, 0]})
    _, r_still, *_ = env.step(np.zeros((1, 3), dtype=np.float32))
    assert r_still == pytest.approx(1.0 + 9.0 + 5.0)  # the paper's reward pays 1 - 1 + 9 here
    env.reset(seed=0, options={"q_TN": [1.0, 0, 0, 0], "omega_B": [0.02, 0.0, 0.0]})
    _, r_moving, *_, info = env.step(np.zeros((1, 3), dtype=np.float32))
    assert info["error_deg"] < 0.25
    expected = np.exp(-np.radians(info["error_deg"]) / (0.28 * np.pi)) + 9.0 + 5.0 * np.exp(-0.02 / 0.05)
    assert r_moving == pytest.approx(expected, rel=1e-3) and r_moving < r_still - 1.0
    # Outside the cone the progress penalty still applies.
    env.reset(seed=0, options={"q_TN": [np.cos(0.5), np.sin(0.5), 0, 0], "omega_B": [-0.02, 0.0, 0.0]})
    _, r_away, *_, info = env.step(np.zeros((1, 3), dtype=np.float32))
    assert info["error_deg"] > 1.0 and r_away < 0.0


def test_rate_margin_penalty_slopes_up_to_the_rate_limit():
    """`rate_margin_penalty`: nothing below `rate_margin_fraction` of the limit, then a linear charge
    that reaches the whole penalty at the limit; above the limit the episode ends as before."""
    reward = {"rate_margin_penalty": 2.0, "rate_margin_fraction": 0.8}
    env = SatelliteSlewEnv(spec={**SHORT, "mission": {**SHORT["mission"], "reward": reward}})
    plain = SatelliteSlewEnv(spec=SHORT)
    limit = 0.5  # the default mission's rate limit, rad/s
    charged = []
    for share in (0.5, 0.85, 0.95):
        rs = []
        for e in (env, plain):
            e.reset(seed=0, options={"q_TN": [np.cos(0.5), np.sin(0.5), 0, 0], "omega_B": [share * limit, 0.0, 0.0]})
            _, r, term, *_ = e.step(np.zeros((1, 3), dtype=np.float32))
            assert not term
            rs.append(r)
        charged.append(rs[1] - rs[0])
    # The rate after the step (no torque: the same rate) sets the charge.
    assert charged[0] == pytest.approx(0.0, abs=1e-9)
    assert charged[1] == pytest.approx(2.0 * 0.05 / 0.2, rel=1e-3)
    assert charged[2] == pytest.approx(2.0 * 0.15 / 0.2, rel=1e-3)
    env.reset(seed=0, options={"q_TN": [1.0, 0, 0, 0], "omega_B": [1.01 * limit, 0.0, 0.0]})
    _, r, term, *_ = env.step(np.zeros((1, 3), dtype=np.float32))
    assert term and r == -50.0


def test_invalid_design_is_refused():
    with pytest.raises(ValueError, match="no actuator"):
        SatelliteSlewEnv(design=np.ones((3, 3, 3), dtype=int))
    assert reference_design(3).sum() == 26 + 2
