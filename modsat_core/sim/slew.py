"""The batched slew simulator: B satellites flying B slews at once.

This is the one implementation of the mission; the gymnasium envs, the PD evaluation and
the learning code are adapters over it. Actions are normalised per wheel unit:
``a in [-1, 1]^(K x 3)`` means a body torque command of ``a * tau_max`` per unit.

Each satellite keeps its own episode clock, so episodes can be reset independently
(``reset(idx, ...)``), which the vector env and the training loop need.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

from modsat_core.grid import ACTUATOR
from modsat_core.sim import dynamics as dyn
from modsat_core.sim import quaternion as quat
from modsat_core.sim.mission import (
    EpisodeDraw,
    eigenaxis_bound_s,
    error_quaternion,
    reward,
    slew_axis_properties,
)
from modsat_core.sim.morphology import design_mass_properties
from modsat_core.spec.jobspec import Mission, ModuleCatalog
from modsat_core.spec.parts import unit_limits


def _put(x: Tensor, idx: Tensor, value: Tensor | float | int) -> Tensor:
    """``x`` with rows ``idx`` set to ``value``, as a new tensor (``x`` is not written)."""
    out = x.clone()
    out[idx] = value
    return out


@dataclass
class Metrics:
    """Per-episode metrics accumulated by the simulator, each (B,)."""

    ret: Tensor
    effort_Nms: Tensor
    peak_rate_rad_s: Tensor
    violated: Tensor
    last_out_of_tol_s: Tensor
    theta0_rad: Tensor
    bound_s: Tensor

    @classmethod
    def zeros(cls, B: int, dtype: torch.dtype, device: torch.device) -> Metrics:
        z = torch.zeros(B, dtype=dtype, device=device)
        return cls(
            z.clone(),
            z.clone(),
            z.clone(),
            torch.zeros(B, dtype=torch.bool, device=device),
            z.clone(),
            z.clone(),
            z.clone(),
        )

    def reset(self, idx: Tensor) -> None:
        for name in ("ret", "effort_Nms", "peak_rate_rad_s", "last_out_of_tol_s"):
            getattr(self, name)[idx] = 0.0
        self.violated[idx] = False


@dataclass(frozen=True)
class Design:
    """A satellite for the simulator: its inertia and its wheel units, numpy float64."""

    grid: np.ndarray  # (N, N, N) int8
    I_B: np.ndarray  # (3, 3)
    actuator_positions_B_m: np.ndarray  # (K, 3)
    #: (K,) each wheel unit's torque and momentum capacity as fractions of the catalog's strongest
    #: (``torque_scale_Nm``, ``momentum_capacity_Nms``); None: every unit is a whole one of those.
    torque_weight: np.ndarray | None = None
    momentum_weight: np.ndarray | None = None

    @property
    def n_actuators(self) -> int:
        return len(self.actuator_positions_B_m)

    def slot_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(K,) torque and momentum fractions of its wheel units (ones without a catalog)."""
        ones = np.ones(self.n_actuators)
        return (
            ones if self.torque_weight is None else self.torque_weight,
            ones if self.momentum_weight is None else self.momentum_weight,
        )

    @classmethod
    def from_grid(cls, grid, modules: ModuleCatalog) -> Design:
        mp = design_mass_properties(grid, modules)
        units = mp.types >= ACTUATOR
        tw = mw = None
        if modules.wheels:
            torque, momentum = unit_limits(mp.types[units], modules)
            tw = torque / modules.torque_scale_Nm
            mw = momentum / (modules.momentum_capacity_Nms or 1.0)
        return cls(
            grid=np.asarray(grid, dtype=np.int8),
            I_B=mp.inertia_B_kgm2,
            actuator_positions_B_m=mp.positions_B_m[units],
            torque_weight=tw,
            momentum_weight=mw,
        )


def slot_masks(designs: list[Design], weighted: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """The (B, K) wheel-unit slots of ``designs``, packed: bool, or with ``weighted`` (a parts catalog)
    each unit's torque fraction, float, and its momentum fraction beside it (else None)."""
    K = max(d.n_actuators for d in designs)
    if not weighted:
        mask = np.zeros((len(designs), K), dtype=bool)
        for i, d in enumerate(designs):
            mask[i, : d.n_actuators] = True
        return mask, None
    torque, momentum = np.zeros((len(designs), K)), np.zeros((len(designs), K))
    for i, d in enumerate(designs):
        tw, mw = d.slot_weights()
        torque[i, : d.n_actuators], momentum[i, : d.n_actuators] = tw, mw
    return torque, momentum


def episode_metrics(
    m: Metrics, phi_rad: Tensor, omega_norm: Tensor, t_s: Tensor, mission: Mission
) -> dict[str, Tensor]:
    """Summary of finished episodes (all tensors (B,)); see DESIGN.md, "Metrics"."""
    tol = mission.tolerance_deg * quat.DEG
    settled_now = (phi_rad <= tol) & (omega_norm <= mission.rate_tolerance_rad_s)
    success = settled_now & ~m.violated
    settling = torch.where(success, m.last_out_of_tol_s, torch.full_like(t_s, math.nan))
    return {
        "success": success,
        "final_error_deg": phi_rad / quat.DEG,
        "final_rate_rad_s": omega_norm,
        "settling_time_s": settling,
        "slew_time_ratio": settling / m.bound_s,
        "eigenaxis_bound_s": m.bound_s,
        "slew_angle_deg": m.theta0_rad / quat.DEG,
        "effort_Nms": m.effort_Nms,
        "peak_rate_rad_s": m.peak_rate_rad_s,
        "safety_violation": m.violated,
        "return": m.ret,
        "duration_s": t_s,
    }


@dataclass
class StepOut:
    reward: Tensor  # (B,)
    terminated: Tensor  # (B,) bool: safety violation
    truncated: Tensor  # (B,) bool: time limit
    phi_rad: Tensor  # (B,)
    tau_c_B: Tensor  # (B, 3) mean body control torque delivered over the step
    final: dict[str, Tensor] = field(default_factory=dict)  # metrics, meaningful where done


class SlewSim:
    """B slews of B satellites (one design per row) on one device and dtype."""

    def __init__(
        self,
        I_B: np.ndarray | Tensor,
        actuator_mask: np.ndarray | Tensor,
        mission: Mission,
        modules: ModuleCatalog,
        *,
        dtype: torch.dtype = torch.float32,
        device: str | torch.device = "cpu",
        momentum_weight: np.ndarray | Tensor | None = None,
        compiled: bool = False,
    ):
        """B satellites given by their inertia (B, 3, 3) and wheel-unit slots (B, K) bool; ``compiled``:
        the physics step fused by ``torch.compile`` (:func:`~modsat_core.sim.dynamics.compiled_physics_step`).

        A floating-point ``actuator_mask`` weighs each slot instead (in [0, 1]): a relaxed grid's
        probability of a wheel unit in a cell, whose torque and momentum the slot scales by it, so
        that the flight is differentiable in the weights (and in ``I_B``; `diffsim-codesign`'s
        relaxed design gradient)."""
        self.mission, self.modules = mission, modules
        self.dtype, self.device = dtype, torch.device(device)
        self.physics_step = dyn.compiled_physics_step() if compiled else dyn.physics_step
        kw: dict[str, Any] = dict(dtype=dtype, device=self.device)
        I_B = torch.as_tensor(I_B, **kw).clone()
        mask = torch.as_tensor(actuator_mask, device=self.device)
        mask = mask.to(dtype).clone() if mask.is_floating_point() else mask.to(torch.bool).clone()
        self.B, self.K = mask.shape
        wheels = modules.actuator_model == "reaction-wheel"
        cap = modules.momentum_capacity_Nms
        self.plant = dyn.Plant(
            I_B=I_B,
            I_B_inv=torch.linalg.inv(I_B),
            actuator_mask=mask,
            tau_max_Nm=modules.torque_scale_Nm,
            h_max_Nms=math.inf if cap is None else cap,
            wheels=wheels,
            n_rad_s=dyn.mean_motion_rad_s(mission.orbit_altitude_km) if mission.gravity_gradient else 0.0,
            orbit_phase_rad=torch.zeros(self.B, **kw),
            tau_residual_B=torch.zeros(self.B, 3, **kw),
            momentum_weight=None if momentum_weight is None else torch.as_tensor(momentum_weight, **kw).clone(),
        )
        self.state = dyn.State(
            q_BN=torch.tensor([[1.0, 0.0, 0.0, 0.0]], **kw).repeat(self.B, 1),
            omega_B=torch.zeros(self.B, 3, **kw),
            h_B=torch.zeros(self.B, self.K, 3, **kw),
            t_s=torch.zeros(self.B, **kw),
        )
        self.q_TN = self.state.q_BN.clone()
        self.steps = torch.zeros(self.B, dtype=torch.long, device=self.device)
        self.phi_prev = torch.zeros(self.B, **kw)
        self.metrics = Metrics.zeros(self.B, dtype, self.device)
        # Scale of the wheel-momentum observation: the capacity, else what one unit stores
        # in one second at full torque.
        self.h_scale_Nms = cap if cap is not None else modules.torque_scale_Nm

    @classmethod
    def from_designs(cls, designs: list[Design], mission: Mission, modules: ModuleCatalog, **kw) -> SlewSim:
        """One satellite per design, wheel-unit slots packed (K = the most actuators). With a parts
        catalog the slots are weighted by each unit's torque and momentum (:meth:`Design.slot_weights`)."""
        mask, momentum = slot_masks(designs, bool(modules.wheels))
        return cls(np.stack([d.I_B for d in designs]), mask, mission, modules, momentum_weight=momentum, **kw)

    def set_plants(
        self, idx: Tensor, I_B: Tensor, actuator_mask: Tensor, momentum_weight: Tensor | None = None
    ) -> None:
        """Replace the satellites ``idx`` (the learning code swaps designs between episodes); with a
        parts catalog, ``momentum_weight`` too (else the slots keep theirs).

        Out of place, as :meth:`reset`: tensors a backward pass may still need are never written."""
        I_B = I_B.to(self.dtype)
        p = self.plant
        mw = p.momentum_weight
        if mw is not None and momentum_weight is not None:
            mw = _put(mw, idx, momentum_weight.to(mw))
        self.plant = replace(
            p,
            I_B=_put(p.I_B, idx, I_B),
            I_B_inv=_put(p.I_B_inv, idx, torch.linalg.inv(I_B)),
            actuator_mask=_put(p.actuator_mask, idx, actuator_mask.to(p.actuator_mask.dtype)),
            momentum_weight=mw,
        )

    def grow_slots(self, K: int) -> None:
        """Room for ``K`` wheel-unit slots where there are fewer: the new slots empty and their wheels
        still (a design learner's draws may carry more units than the designs it started with)."""
        pad = K - self.K
        if pad <= 0:
            return
        p, st = self.plant, self.state
        mw = p.momentum_weight
        self.plant = replace(
            p,
            actuator_mask=torch.cat([p.actuator_mask, p.actuator_mask.new_zeros(self.B, pad)], dim=1),
            momentum_weight=None if mw is None else torch.cat([mw, mw.new_zeros(self.B, pad)], dim=1),
        )
        self.state = dyn.State(
            st.q_BN, st.omega_B, torch.cat([st.h_B, st.h_B.new_zeros(self.B, pad, 3)], dim=1), st.t_s
        )
        self.K = K

    # ------------------------------------------------------------------ reset / observe
    def reset(self, idx: Tensor | list[int], draws: list[EpisodeDraw]) -> None:
        """Start new episodes for satellites ``idx`` (len b) from ``draws`` (len b).

        Every tensor is replaced, not written in place, so a reset between steps whose graph is
        still to be backpropagated (the first-order learner) leaves that graph intact."""
        idx = torch.as_tensor(idx, dtype=torch.long, device=self.device)
        kw: dict[str, Any] = dict(dtype=self.dtype, device=self.device)
        st = self.state
        q_BN = torch.tensor(np.stack([d.q_BN for d in draws]), **kw)
        self.state = dyn.State(
            q_BN=_put(st.q_BN, idx, q_BN),
            omega_B=_put(st.omega_B, idx, torch.tensor(np.stack([d.omega_B for d in draws]), **kw)),
            h_B=_put(st.h_B, idx, 0.0),
            t_s=_put(st.t_s, idx, 0.0),
        )
        self.q_TN = _put(self.q_TN, idx, torch.tensor(np.stack([d.q_TN for d in draws]), **kw))
        self.plant = replace(
            self.plant,
            tau_residual_B=_put(
                self.plant.tau_residual_B, idx, torch.tensor(np.stack([d.tau_residual_B for d in draws]), **kw)
            ),
            orbit_phase_rad=_put(
                self.plant.orbit_phase_rad, idx, torch.tensor([d.orbit_phase_rad for d in draws], **kw)
            ),
        )
        self.steps = _put(self.steps, idx, 0)
        q_e = error_quaternion(self.q_TN[idx], q_BN)
        self.phi_prev = _put(self.phi_prev, idx, quat.error_angle(q_e))
        self.metrics.reset(idx)
        theta, I_axis, tau_axis = slew_axis_properties(
            q_e, self.plant.I_B[idx].detach(), self.plant.n_actuators[idx].detach(), self.plant.tau_max_Nm
        )
        self.metrics.theta0_rad[idx] = theta
        self.metrics.bound_s[idx] = eigenaxis_bound_s(theta, I_axis, tau_axis, self.mission.rate_limit_rad_s)

    def detach(self) -> None:
        """Cut the graph: the flight goes on from the same state, with no history behind it (the
        first-order learner, between gradient windows)."""
        st = self.state
        self.state = dyn.State(st.q_BN.detach(), st.omega_B.detach(), st.h_B.detach(), st.t_s.detach())
        self.phi_prev = self.phi_prev.detach()

    def load_flight(self, d: dict[str, Tensor]) -> None:
        """Restore the flights :meth:`flight_state` saved (a resumed first-order run)."""
        kw: dict[str, Any] = dict(dtype=self.dtype, device=self.device)
        self.state = dyn.State(
            q_BN=d["q_BN"].to(**kw), omega_B=d["omega_B"].to(**kw), h_B=d["h_B"].to(**kw), t_s=d["t_s"].to(**kw)
        )
        self.q_TN = d["q_TN"].to(**kw)
        self.steps = d["steps"].to(self.device)
        self.phi_prev = d["phi_prev"].to(**kw)
        self.plant = replace(
            self.plant, tau_residual_B=d["tau_residual_B"].to(**kw), orbit_phase_rad=d["orbit_phase_rad"].to(**kw)
        )
        self.metrics.violated = d["violated"].to(self.device)

    def flight_state(self) -> dict[str, Tensor]:
        """What :meth:`load_flight` needs to continue these flights exactly (CPU tensors)."""
        st, p = self.state, self.plant
        out = {
            "q_BN": st.q_BN,
            "omega_B": st.omega_B,
            "h_B": st.h_B,
            "t_s": st.t_s,
            "q_TN": self.q_TN,
            "steps": self.steps,
            "phi_prev": self.phi_prev,
            "tau_residual_B": p.tau_residual_B,
            "orbit_phase_rad": p.orbit_phase_rad,
            "violated": self.metrics.violated,
        }
        return {k: v.detach().cpu().clone() for k, v in out.items()}

    def error_quaternion(self) -> Tensor:
        """(B, 4) ``q_BT`` with non-negative scalar part."""
        return error_quaternion(self.q_TN, self.state.q_BN)

    def observation(self) -> Tensor:
        """Flat observation of the whole satellite, (B, 11 [+ 3K]).

        ``[q_BT (4), dq_BT/dt (4), omega_B (3)]`` and, with reaction wheels, each unit's
        momentum divided by ``h_scale_Nms`` (3 per unit).
        """
        q_e = self.error_quaternion()
        parts = [q_e, quat.derivative(q_e, self.state.omega_B), self.state.omega_B]
        if self.plant.wheels:
            parts.append((self.state.h_B / self.h_scale_Nms).reshape(self.B, -1))
        return torch.cat(parts, dim=-1)

    # ------------------------------------------------------------------ step
    def step(self, action: Tensor) -> StepOut:
        """Advance all satellites one control step; action (B, K, 3) in [-1, 1]."""
        m, acc = self.mission, self.metrics
        a = action.to(self.dtype).clamp(-1.0, 1.0) * self.plant.slots.unsqueeze(-1)
        tau_cmd = a * self.plant.tau_max_Nm
        self.state, tau_c = dyn.control_step(
            self.state, self.plant, tau_cmd, m.physics_dt_s, m.frame_skip, self.physics_step
        )
        self.steps += 1
        phi = quat.error_angle(self.error_quaternion())
        omega_norm = self.state.omega_B.norm(dim=-1)
        rew, in_tol, violated = reward(phi, self.phi_prev, omega_norm, m, m.episode_steps - self.steps)
        self.phi_prev = phi
        dt_c = m.control_dt_s
        # The episode's metrics carry no graph: a differentiable flight backpropagates its own cost.
        acc.ret += rew.detach()
        acc.effort_Nms += tau_cmd.detach().abs().sum(dim=(1, 2)) * dt_c
        acc.peak_rate_rad_s = torch.maximum(acc.peak_rate_rad_s, omega_norm.detach())
        acc.violated |= violated
        acc.last_out_of_tol_s = torch.where(in_tol, acc.last_out_of_tol_s, self.state.t_s.detach())
        truncated = (self.steps >= m.episode_steps) & ~violated
        out = StepOut(reward=rew, terminated=violated, truncated=truncated, phi_rad=phi, tau_c_B=tau_c)
        if bool((violated | truncated).any()):
            out.final = episode_metrics(acc, phi, omega_norm, self.state.t_s, m)
        return out
