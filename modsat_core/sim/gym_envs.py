"""Gymnasium adapters over :class:`~modsat_core.sim.slew.SlewSim`: control of a given design.

``modsat/SatelliteSlew-v0`` (registered on import of :mod:`modsat_core`) is one
satellite; :class:`SatelliteSlewVectorEnv` steps ``num_envs`` of them in one batch with the
same per-episode draws, so a vector env and single envs seeded ``seed + i`` fly the same
trajectories.

Observation (float32): ``[q_BT (4), dq_BT/dt (4), omega_B (3)]`` plus, with reaction
wheels, each unit's momentum divided by its capacity (3 per unit), clipped to the finite
box of ``observation_space`` (reached only far outside the safety limit). Action: ``(K, 3)`` in
[-1, 1], each unit's body torque command as a fraction of the torque scale.

``reset(seed=..., options={"q_BN": wxyz, "q_TN": wxyz, "omega_B": xyz})`` fixes the
initial attitude, target attitude and initial body rate. ``info`` has ``q_BN``, ``q_TN``,
``omega_B``, ``h_B`` (total wheel momentum, body frame), ``h_units_B`` (per unit),
``error_deg`` and, when an episode ends, ``episode`` (the metrics of DESIGN.md).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode

from modsat_core.grid import ACTUATOR, STRUCTURE
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec, parse_spec

_DTYPES = {"float32": torch.float32, "float64": torch.float64}


def reference_design(n: int = 3) -> np.ndarray:
    """The full N x N x N cube of structure modules whose centre module is the one actuator."""
    grid = np.full((n, n, n), STRUCTURE, dtype=np.int8)
    grid[n // 2, n // 2, n // 2] = ACTUATOR
    return grid


def _resolve(spec: JobSpec | dict | None, design) -> tuple[JobSpec, Design]:
    if spec is None:
        spec = JobSpec()
    elif isinstance(spec, dict):
        spec = parse_spec(spec)
    if design is None:
        design = spec.design.fixed_design
    if design is None:
        design = reference_design(spec.design.grid_size)
    from modsat_core.grid import validity_problem

    problem = validity_problem(design)
    if problem:
        raise ValueError(f"design is not a valid satellite: {problem}")
    return spec, Design.from_grid(design, spec.modules)


OMEGA_OBS_BOUND_RAD_S = 10.0  # 20 times the default safety limit: reached only by a broken spec


def _spaces(sim: SlewSim) -> tuple[spaces.Box, spaces.Box]:
    """Finite observation bounds: |q_BT| <= 1, |dq/dt| <= |omega|/2, |omega| <= 10 rad/s, and
    wheel momentum at most its capacity (or what full torque stores in one episode)."""
    obs_dim = sim.observation().shape[-1]
    high = np.empty(obs_dim, dtype=np.float32)
    high[:4] = 1.0
    high[4:8] = 0.5 * OMEGA_OBS_BOUND_RAD_S
    high[8:11] = OMEGA_OBS_BOUND_RAD_S
    episode_s = sim.mission.episode_steps * sim.mission.control_dt_s
    high[11:] = 1.0 if sim.modules.momentum_capacity_Nms is not None else max(1.0, episode_s)
    obs = spaces.Box(-high, high, dtype=np.float32)
    act = spaces.Box(-1.0, 1.0, shape=(sim.K, 3), dtype=np.float32)
    return obs, act


def _info(sim: SlewSim, i: int | slice) -> dict[str, np.ndarray]:
    st = sim.state
    return {
        "q_BN": st.q_BN[i].cpu().numpy().astype(np.float64),
        "q_TN": sim.q_TN[i].cpu().numpy().astype(np.float64),
        "omega_B": st.omega_B[i].cpu().numpy().astype(np.float64),
        "h_B": st.h_B[i].sum(dim=-2).cpu().numpy().astype(np.float64),
        "h_units_B": st.h_B[i].cpu().numpy().astype(np.float64),
        "error_deg": np.degrees(sim.phi_prev[i].cpu().numpy().astype(np.float64)),
    }


class SatelliteSlewEnv(gym.Env):
    """One satellite of a given design flying slews (see the module docstring)."""

    metadata = {"render_modes": []}
    observation_space: spaces.Box  # what _spaces builds (gym.Env declares the base Space)

    def __init__(self, spec: JobSpec | dict | None = None, design=None, dtype: str = "float64", device: str = "cpu"):
        self.spec_model, self.design = _resolve(spec, design)
        self.sim = SlewSim.from_designs(
            [self.design], self.spec_model.mission, self.spec_model.modules, dtype=_DTYPES[dtype], device=device
        )
        self.observation_space, self.action_space = _spaces(self.sim)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self.sim.reset([0], [draw_episode(self.np_random, self.spec_model.mission, options)])
        return self._obs(), _info(self.sim, 0)

    def step(self, action):
        a = torch.as_tensor(np.asarray(action), dtype=self.sim.dtype, device=self.sim.device)
        out = self.sim.step(a.reshape(1, self.sim.K, 3))
        terminated, truncated = bool(out.terminated[0]), bool(out.truncated[0])
        info = _info(self.sim, 0)
        if terminated or truncated:
            info["episode"] = {k: v[0].item() for k, v in out.final.items()}
        return self._obs(), float(out.reward[0]), terminated, truncated, info

    def _obs(self) -> np.ndarray:
        obs = self.sim.observation()[0].cpu().numpy().astype(np.float32)
        return np.clip(obs, self.observation_space.low, self.observation_space.high)


class SatelliteSlewVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` satellites of one design in one batched simulator (autoreset: next step).

    ``reset(seed=s)`` seeds sub-env ``i`` with ``s + i`` (as gymnasium's SyncVectorEnv
    does); ``options`` values may be given per env as arrays with a leading ``num_envs``
    axis, or once for all.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    single_observation_space: spaces.Box  # what _spaces builds (VectorEnv declares the base Space)

    def __init__(
        self,
        num_envs: int,
        spec: JobSpec | dict | None = None,
        design=None,
        dtype: str = "float64",
        device: str = "cpu",
    ):
        self.num_envs = num_envs
        self.spec_model, self.design = _resolve(spec, design)
        self.sim = SlewSim.from_designs(
            [self.design] * num_envs,
            self.spec_model.mission,
            self.spec_model.modules,
            dtype=_DTYPES[dtype],
            device=device,
        )
        self.single_observation_space, self.single_action_space = _spaces(self.sim)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self._rngs = [seeding.np_random()[0] for _ in range(num_envs)]
        self._autoreset = np.zeros(num_envs, dtype=bool)

    def _options_for(self, options: dict[str, Any] | None, i: int) -> dict[str, Any] | None:
        if not options:
            return None
        out = {}
        for k, v in options.items():
            arr = np.asarray(v, dtype=np.float64)
            out[k] = arr[i] if arr.ndim == 2 else arr
        return out

    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            seeds = [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} envs")
            self._rngs = [seeding.np_random(s)[0] for s in seeds]
        idx = list(range(self.num_envs))
        self.sim.reset(
            idx, [draw_episode(self._rngs[i], self.spec_model.mission, self._options_for(options, i)) for i in idx]
        )
        self._autoreset[:] = False
        return self._obs(), _info(self.sim, slice(None))

    def step(self, actions):
        a = torch.as_tensor(np.asarray(actions), dtype=self.sim.dtype, device=self.sim.device)
        restart = self._autoreset.copy()
        out = self.sim.step(a.reshape(self.num_envs, self.sim.K, 3))
        rewards = out.reward.cpu().numpy().astype(np.float64)
        terminated = out.terminated.cpu().numpy().copy()
        truncated = out.truncated.cpu().numpy().copy()
        # Sub-envs that ended on the previous step restart now: their action is ignored and
        # their result is the reset observation with zero reward (NEXT_STEP autoreset).
        if restart.any():
            idx = np.flatnonzero(restart)
            self.sim.reset(idx.tolist(), [draw_episode(self._rngs[i], self.spec_model.mission) for i in idx])
            rewards[restart], terminated[restart], truncated[restart] = 0.0, False, False
        ended = terminated | truncated
        info = _info(self.sim, slice(None))
        if ended.any():
            info["episode"] = {k: v.cpu().numpy() for k, v in out.final.items()}
            info["_episode"] = ended.copy()
        self._autoreset = ended
        return self._obs(), rewards, terminated, truncated, info

    def _obs(self) -> np.ndarray:
        obs = self.sim.observation().cpu().numpy().astype(np.float32)
        return np.clip(obs, self.single_observation_space.low, self.single_observation_space.high)
