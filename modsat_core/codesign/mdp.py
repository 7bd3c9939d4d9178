"""The unified design + control MDP, batched: B episodes, each in its own phase.

An episode starts from a seed module (one actuator at the grid centre). For
``design_steps`` steps every cell's 3 action values are read by argmax as its new type
(a synchronous neural-cellular-automaton update); these steps earn no reward. The final
grid must be valid (face-connected, with an actuator): if it is not, the episode ends
with the invalid-design penalty; if it is, the satellite is built and flies one slew of
the mission, exactly as :class:`~modsat_core.sim.slew.SlewSim` defines it.

With a fixed design (``td3-control``, and the GA's inner loop) there is no design phase.

The simulator has one wheel-unit slot per grid cell (K = C = N^3), so per-cell actions
are wheel commands directly; non-actuator slots are masked out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from modsat_core.codesign.features import CellObs, PhysState, cell_observation
from modsat_core.grid import ACTUATOR, valid_mask
from modsat_core.sim.conditions import Flight
from modsat_core.sim.mission import draw_episode, return_bounds
from modsat_core.sim.morphology import (
    mass_properties_batched,
    seed_component_batched,
)
from modsat_core.sim.slew import SlewSim
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.limits import REPLAY_STATE
from modsat_core.spec.sections import DesignSpace, Mission


def effective_invalid_penalty(design: DesignSpace, mission: Mission) -> float:
    """The design space's penalty, lowered if needed below the worst return of any valid design."""
    low, _ = return_bounds(mission)
    return min(design.invalid_penalty, low - 1.0)


def seed_grid(N: int) -> np.ndarray:
    g = np.zeros((N, N, N), dtype=np.int64)
    g[N // 2, N // 2, N // 2] = ACTUATOR
    return g


@dataclass
class Compact:
    """What the replay buffer keeps of a state (B rows); features are rebuilt from it."""

    grid: Tensor  # (B, C) uint8
    design_step: Tensor  # (B,) int16
    q_BN: Tensor  # (B, 4) float32
    q_TN: Tensor  # (B, 4) float32
    omega_B: Tensor  # (B, 3) float32
    h_cells: Tensor  # (B, C, 3) float16, wheel momentum / scale
    #: (B, C, 3) float16, the action commanded at the previous control step (zero at a flight's first
    #: step and while designing); None where the policy does not observe it (`training.observe_last_command`).
    last_cmd: Tensor | None = None

    #: The replay's state fields, in its order (spec.limits.REPLAY_STATE: the layout's one table).
    FIELDS = tuple(name for name, _, _ in REPLAY_STATE)

    def as_dict(self, prefix: str = "") -> dict[str, Tensor]:
        """The replay's state fields (not the last command: the replay keeps the observed state's only,
        as ``obs_last_cmd``; the next state's is the transition's action, :func:`next_last_command`)."""
        return {prefix + k: getattr(self, k) for k in self.FIELDS}

    @classmethod
    def from_dict(cls, d: dict[str, Tensor], prefix: str = "", last_cmd: Tensor | None = None) -> Compact:
        return cls(**{k: d[prefix + k] for k in cls.FIELDS}, last_cmd=last_cmd)


def next_last_command(design_step: Tensor, action: Tensor, design_steps: int) -> Tensor:
    """(B, C, 3) the last command of the states a transition led to: its action where the observed state
    flew (``design_step`` (B,) >= ``design_steps``), zero where it was designing (the flight it led to
    starts with no command)."""
    flew = (design_step.long() >= design_steps).reshape(-1, 1, 1)
    return action * flew.to(action.dtype)


def observe_compact(c: Compact, N: int, design_steps: int, rate_limit_rad_s: float) -> CellObs:
    """Rebuild per-cell observations from compact rows (used when sampling the buffer); with the last
    command where the rows hold it."""
    B = c.grid.shape[0]
    phys = PhysState(q_BN=c.q_BN.float(), q_TN=c.q_TN.float(), omega_B=c.omega_B.float(), h_cells=c.h_cells.float())
    last = None if c.last_cmd is None else c.last_cmd.float()
    return cell_observation(
        c.grid.long().reshape(B, N, N, N), c.design_step.long(), design_steps, phys, rate_limit_rad_s, last
    )


@dataclass
class EnvStep:
    reward: Tensor  # (B,)
    terminal: Tensor  # (B,) bool: no bootstrapping (safety violation, invalid design)
    done: Tensor  # (B,) bool: the episode ended (terminal or time limit); it was reset
    next_state: Compact  # the state the transition led to, before any reset
    finished: list[dict]  # one summary per finished episode


class CoDesignEnv:
    """B parallel episodes of the design + control MDP (see the module docstring)."""

    def __init__(self, spec: JobSpec, num_envs: int, *, seed: int, fixed_grid=None, device: str = "cpu"):
        self.spec = spec
        self.N = spec.design.grid_size if fixed_grid is None else np.asarray(fixed_grid).shape[0]
        self.C = self.N**3
        self.D = 0 if fixed_grid is not None else spec.design.design_steps
        self.B = num_envs
        self.device = torch.device(device)
        self.fixed_grid = None if fixed_grid is None else torch.as_tensor(np.asarray(fixed_grid), device=self.device)
        self.penalty = effective_invalid_penalty(spec.design, spec.mission)
        eye = np.tile(np.eye(3), (num_envs, 1, 1))
        self.sim = SlewSim(
            eye,
            np.zeros((num_envs, self.C), dtype=bool),
            spec.mission,
            spec.modules,
            dtype=torch.float32,
            device=self.device,
        )
        self.rngs = [np.random.default_rng([seed, 1, i]) for i in range(num_envs)]
        self.design_rng = np.random.default_rng([seed, 2])
        self.grids = torch.zeros(num_envs, self.N, self.N, self.N, dtype=torch.long, device=self.device)
        self.design_step = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self.ep_return = torch.zeros(num_envs, device=self.device)
        # The last command (`training.observe_last_command`): what each row commanded at its previous
        # control step, the policy's own action before any delay or weakening; zero when a flight starts.
        self.observe_last = spec.training.observe_last_command
        self.last_cmd = torch.zeros(num_envs, self.C, 3, device=self.device)
        # Whether new flights draw conditions from `randomise`: from the start, or once its curriculum
        # (`training.randomise_after_success`, read from the learning curve) switches it on: the trainer sets it.
        self.randomising = spec.randomise.active and spec.training.randomise_after_success is None
        # Domain randomisation (the `randomise` section): the flight between the actor and the sim,
        # its conditions drawn per flight from a stream of their own.
        self.flight = Flight(self.sim, max_delay=spec.randomise.delay_steps if spec.randomise.active else 0, seed=seed)
        self.cond_rng = np.random.default_rng([seed, 3])
        self._reset(torch.arange(num_envs, device=self.device))

    # ----------------------------------------------------------------- state
    def compact(self) -> Compact:
        """The actor's observation of every env: with sensor noise (`randomise`), the measured state."""
        st = self.flight.view().state if self.flight.noisy else self.sim.state
        return Compact(
            grid=self.grids.reshape(self.B, -1).to(torch.uint8),
            design_step=self.design_step.to(torch.int16),
            q_BN=st.q_BN.clone(),
            q_TN=self.sim.q_TN.clone(),
            omega_B=st.omega_B.clone(),
            h_cells=(st.h_B / self.sim.h_scale_Nms).to(torch.float16),
            last_cmd=self.last_cmd.to(torch.float16) if self.observe_last else None,
        )

    def observe(self) -> CellObs:
        return observe_compact(self.compact(), self.N, self.D, self.spec.mission.rate_limit_rad_s)

    def _reset(self, idx: Tensor) -> None:
        """Start new episodes: the seed grid, or straight into flight for a fixed design."""
        if len(idx) == 0:
            return
        if self.fixed_grid is not None:
            self.grids[idx] = self.fixed_grid
            self.design_step[idx] = 0
            self._start_flight(idx)
        else:
            self.grids[idx] = torch.as_tensor(seed_grid(self.N), device=self.device)
            self.design_step[idx] = 0
        self.ep_return[idx] = 0.0
        self.last_cmd[idx] = 0.0

    def _start_flight(self, idx: Tensor) -> None:
        if len(idx) == 0:
            return
        m = self.spec.modules
        _, _, I_B = mass_properties_batched(self.grids[idx], m.module_mass_kg, m.module_size_m, dtype=torch.float32)
        self.sim.set_plants(idx, I_B, self.grids[idx].reshape(len(idx), -1) >= ACTUATOR)
        draws = [draw_episode(self.rngs[int(i)], self.spec.mission) for i in idx.tolist()]
        self.last_cmd[idx] = 0.0
        if self.randomising:
            I_model = I_B.double().cpu().numpy()
            draws = self.flight.randomise(idx, self.spec.randomise, self.cond_rng, I_model, draws)
        self.sim.reset(idx, draws)
        self.flight.reset_rows(idx)

    # ----------------------------------------------------------------- step
    def step(self, actions: Tensor) -> EnvStep:
        """Apply per-cell actions (B, C, 3) in [-1, 1]; finished episodes are reset."""
        B = self.B
        designing = self.design_step < self.D
        flying = ~designing
        reward = torch.zeros(B, device=self.device)
        terminal = torch.zeros(B, dtype=torch.bool, device=self.device)
        done = torch.zeros(B, dtype=torch.bool, device=self.device)
        finished: list[dict] = []

        if bool(flying.any()):
            out = self.sim.step(self.flight.apply(actions))  # late and weak under `randomise`
            self.last_cmd = torch.where(flying.reshape(B, 1, 1), actions.to(self.last_cmd.dtype), self.last_cmd)
            reward = torch.where(flying, out.reward, reward)
            terminal = flying & out.terminated
            done = flying & (out.terminated | out.truncated)
        if bool(designing.any()):
            idx = designing.nonzero().squeeze(-1)
            new_types = actions[idx].argmax(dim=-1).reshape(len(idx), self.N, self.N, self.N)
            self.grids[idx] = new_types
            self.design_step[idx] += 1
            last = idx[self.design_step[idx] == self.D]
            if len(last):
                if self.spec.design.repair:
                    self.grids[last] = seed_component_batched(self.grids[last])
                valid = valid_mask(self.grids[last])
                bad, good = last[~valid], last[valid]
                reward[bad] = self.penalty
                terminal[bad] = True
                done[bad] = True
                self._start_flight(good)

        self.ep_return += reward
        next_state = self.compact()
        for i in done.nonzero().squeeze(-1).tolist():
            row = {
                "return": float(self.ep_return[i]),
                "grid": self.grids[i].cpu().numpy().tolist(),
                "valid": bool(flying[i]),
            }
            if flying[i]:
                row.update({k: (v[i].item()) for k, v in out.final.items()})
            else:
                row.update({"success": False})
            finished.append(row)
        self._reset(done.nonzero().squeeze(-1))
        return EnvStep(reward=reward, terminal=terminal, done=done, next_state=next_state, finished=finished)

    # ----------------------------------------------------------------- checkpoint
    def state_dict(self) -> dict:
        st, p = self.sim.state, self.sim.plant
        return {
            "grids": self.grids.clone(),
            "design_step": self.design_step.clone(),
            "ep_return": self.ep_return.clone(),
            "q_BN": st.q_BN.clone(),
            "omega_B": st.omega_B.clone(),
            "h_B": st.h_B.clone(),
            "t_s": st.t_s.clone(),
            "q_TN": self.sim.q_TN.clone(),
            "steps": self.sim.steps.clone(),
            "phi_prev": self.sim.phi_prev.clone(),
            "I_B": p.I_B.clone(),
            "mask": p.actuator_mask.clone(),
            "phase": p.orbit_phase_rad.clone(),
            "tau_res": p.tau_residual_B.clone(),
            "metrics": {k: v.clone() for k, v in vars(self.sim.metrics).items()},
            "rngs": [r.bit_generator.state for r in self.rngs],
            "design_rng": self.design_rng.bit_generator.state,
            "flight": self.flight.state_dict(),
            "cond_rng": self.cond_rng.bit_generator.state,
            "last_cmd": self.last_cmd.clone(),
        }

    def load_state_dict(self, d: dict) -> None:
        self.grids.copy_(d["grids"])
        self.design_step.copy_(d["design_step"])
        self.ep_return.copy_(d["ep_return"])
        st = self.sim.state
        for name in ("q_BN", "omega_B", "h_B", "t_s"):
            getattr(st, name).copy_(d[name])
        self.sim.q_TN.copy_(d["q_TN"])
        self.sim.steps.copy_(d["steps"])
        self.sim.phi_prev.copy_(d["phi_prev"])
        all_idx = torch.arange(self.B, device=self.device)
        self.sim.set_plants(all_idx, d["I_B"], d["mask"])
        self.sim.plant.orbit_phase_rad.copy_(d["phase"])
        self.sim.plant.tau_residual_B.copy_(d["tau_res"])
        for k, v in d["metrics"].items():
            getattr(self.sim.metrics, k).copy_(v)
        for r, s in zip(self.rngs, d["rngs"]):
            r.bit_generator.state = s
        self.design_rng.bit_generator.state = d["design_rng"]
        if "flight" in d:  # checkpoints from before domain randomisation have none (and need none)
            self.flight.load_state_dict(d["flight"])
            self.cond_rng.bit_generator.state = d["cond_rng"]
        if "last_cmd" in d:  # checkpoints from before the last command have none (their specs do not observe it)
            self.last_cmd.copy_(d["last_cmd"])
