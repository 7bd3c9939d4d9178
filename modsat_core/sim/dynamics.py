"""Batched rigid-body attitude dynamics with reaction-wheel units, in torch.

Equations (body frame B, inertial frame N), for B satellites at once::

    dq_BN/dt  = 1/2 q_BN (x) [0, omega_B]                       (kinematics)
    I omega_B' = -omega_B x (I omega_B + h_B) - u + tau_d         (reaction wheels)
    h_B'       = u                                                (stored wheel momentum)

where ``u`` is the torque the motors apply to the wheels, so the body feels ``-u``. The
commanded quantity everywhere in modsat is the *body* control torque ``tau_c = -u``, so
that the same action means the same thing in both actuator models. In ``ideal`` mode
there is no momentum state and the equation is the paper's eq. (5):
``I omega_B' = -omega_B x I omega_B + tau_c + tau_d``.

Each actuator module is a 3-axis wheel unit aligned with the body axes, with a per-axis
torque limit ``tau_max`` and, optionally, a per-axis momentum capacity ``h_max``. As in
Basilisk's wheel model, a wheel at capacity cannot accelerate further in that direction;
here the torque is limited at the start of each physics step so that the wheel lands
exactly on its capacity, which keeps total angular momentum conserved to integrator
precision (no clamping of the state).

Disturbances: gravity gradient ``3 n^2 r_B x (I r_B)`` for a circular orbit in the N
x-y plane (``r_B``: unit position vector from the Earth's centre, in B), and a constant
residual torque per satellite.

Integration: classic RK4 with the control held over ``frame_skip`` physics steps. The
wheel torque is constant within a step, so ``h_B`` is integrated exactly and its sum
enters the rate equation as a linear function of time.
"""

from __future__ import annotations

import math
import os
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import cast

import torch
from torch import Tensor

from modsat_core.sim import quaternion as quat

MU_EARTH_M3_S2 = 3.986004418e14
R_EARTH_M = 6378.1363e3


def mean_motion_rad_s(altitude_km: float) -> float:
    """Mean motion ``n = sqrt(mu / r^3)`` of a circular orbit."""
    r = R_EARTH_M + altitude_km * 1e3
    return math.sqrt(MU_EARTH_M3_S2 / r**3)


@dataclass(frozen=True)
class Plant:
    """Per-satellite constants, batched over B satellites with K wheel-unit slots each.

    Attributes:
        I_B: (B, 3, 3) inertia about the centre of mass, kg m^2.
        I_B_inv: (B, 3, 3) its inverse.
        actuator_mask: (B, K) bool, which wheel-unit slots exist (or float weights in [0, 1],
            a relaxed grid's fraction of a unit in each slot).
        tau_max_Nm: per-axis torque limit of one wheel unit.
        h_max_Nms: per-axis momentum capacity of one wheel unit (``inf``: unlimited).
        wheels: True for the reaction-wheel model, False for the paper's ideal torque.
        n_rad_s: orbit mean motion; 0 disables the gravity-gradient torque.
        orbit_phase_rad: (B,) argument of latitude at t = 0.
        tau_residual_B: (B, 3) constant disturbance torque, N m.
        momentum_weight: (B, K) each slot's momentum capacity as a fraction of ``h_max`` (a parts
            catalog's wheel units differ in torque and in momentum; None: the slot's ``actuator_mask``).
    """

    I_B: Tensor
    I_B_inv: Tensor
    actuator_mask: Tensor
    tau_max_Nm: float
    h_max_Nms: float
    wheels: bool
    n_rad_s: float
    orbit_phase_rad: Tensor
    tau_residual_B: Tensor
    momentum_weight: Tensor | None = None

    @property
    def batch_size(self) -> int:
        return self.I_B.shape[0]

    @property
    def n_actuators(self) -> Tensor:
        """(B,) number of wheel units of each satellite."""
        return self.actuator_mask.sum(dim=1)

    @property
    def slots(self) -> Tensor:
        """(B, K) bool, the slots that hold a wheel unit (whole or, weighted, a fraction of one)."""
        return self.actuator_mask != 0

    @property
    def box_Nm(self) -> Tensor:
        """(B, 1) half-width of the body-torque box the wheel units span, ``K tau_max`` per axis, N m."""
        return self.n_actuators.to(self.I_B.dtype).unsqueeze(-1) * self.tau_max_Nm

    def index(self, idx: Tensor) -> Plant:
        """The plants of a subset of satellites (idx: (b,) long or (B,) bool)."""
        return replace(
            self,
            I_B=self.I_B[idx],
            I_B_inv=self.I_B_inv[idx],
            actuator_mask=self.actuator_mask[idx],
            orbit_phase_rad=self.orbit_phase_rad[idx],
            tau_residual_B=self.tau_residual_B[idx],
            momentum_weight=None if self.momentum_weight is None else self.momentum_weight[idx],
        )


@dataclass(frozen=True)
class State:
    """Physical state of B satellites.

    Attributes:
        q_BN: (B, 4) attitude, wxyz.
        omega_B: (B, 3) body rate, rad/s.
        h_B: (B, K, 3) momentum stored in each wheel unit, N m s (zeros in ideal mode).
        t_s: (B,) time since the episode start, s.
    """

    q_BN: Tensor
    omega_B: Tensor
    h_B: Tensor
    t_s: Tensor


def _matvec(M: Tensor, v: Tensor) -> Tensor:
    # Elementwise form: much faster than bmm for millions of 3x3 products on CPU.
    return (M * v.unsqueeze(-2)).sum(-1)


def gravity_gradient_B(q_BN: Tensor, I_B: Tensor, t_s: Tensor, n_rad_s: float, phase_rad: Tensor) -> Tensor:
    """Gravity-gradient torque ``3 n^2 r_B x (I r_B)``, (B, 3) N m."""
    u = n_rad_s * t_s + phase_rad
    r_N = torch.stack((torch.cos(u), torch.sin(u), torch.zeros_like(u)), dim=-1)
    r_B = quat.rotate_inverse(q_BN, r_N)
    return 3.0 * n_rad_s**2 * torch.cross(r_B, _matvec(I_B, r_B), dim=-1)


def external_torque_B(state_q: Tensor, t_s: Tensor, plant: Plant) -> Tensor:
    tau = plant.tau_residual_B.expand(state_q.shape[0], 3)
    if plant.n_rad_s > 0.0:
        tau = tau + gravity_gradient_B(state_q, plant.I_B, t_s, plant.n_rad_s, plant.orbit_phase_rad)
    return tau


def wheel_torque(h_B: Tensor, tau_cmd_B: Tensor, plant: Plant, dt_s: float) -> Tensor:
    """Torque ``u`` actually applied to each wheel unit over one physics step, (B, K, 3).

    ``tau_cmd_B`` (B, K, 3) is the commanded body torque of each unit; it is clipped to
    the per-axis limit, masked to existing units, and (with a capacity) limited so the
    wheel momentum stays within ``[-h_max, h_max]`` at the end of the step.
    """
    mask = plant.actuator_mask.unsqueeze(-1)
    u = -tau_cmd_B.clamp(-plant.tau_max_Nm, plant.tau_max_Nm) * mask
    if plant.wheels and math.isfinite(plant.h_max_Nms):
        # a weighted slot (a relaxed grid's) is that fraction of a unit: of its capacity too; a catalog's
        # wheel unit has its own capacity (momentum_weight)
        h_max: Tensor | float
        if plant.momentum_weight is not None:
            h_max = plant.h_max_Nms * plant.momentum_weight.unsqueeze(-1)
        else:
            h_max = plant.h_max_Nms * mask if mask.is_floating_point() else plant.h_max_Nms
        u = torch.minimum(torch.maximum(u, (-h_max - h_B) / dt_s), (h_max - h_B) / dt_s)
    return u


def _rates(q: Tensor, w: Tensor, h_tot: Tensor, tau_c: Tensor, t: Tensor, plant: Plant) -> tuple[Tensor, Tensor]:
    H_B = _matvec(plant.I_B, w) + h_tot
    tau = tau_c - torch.cross(w, H_B, dim=-1) + external_torque_B(q, t, plant)
    return quat.derivative(q, w), _matvec(plant.I_B_inv, tau)


def physics_step(state: State, plant: Plant, tau_cmd_B: Tensor, dt_s: float) -> tuple[State, Tensor]:
    """One RK4 step of length ``dt_s`` with the command held.

    Args:
        tau_cmd_B: (B, K, 3) commanded body torque of each wheel unit, N m.
    Returns:
        The new state and the body control torque delivered during the step, (B, 3) N m
        (after the per-axis limit and, for wheels, the momentum capacity).
    """
    if plant.wheels:
        u = wheel_torque(state.h_B, tau_cmd_B, plant, dt_s)
        u_tot = u.sum(dim=1)
        tau_c = -u_tot
        h0 = state.h_B.sum(dim=1)
    else:
        tau_c = (tau_cmd_B.clamp(-plant.tau_max_Nm, plant.tau_max_Nm) * plant.actuator_mask.unsqueeze(-1)).sum(1)
        u_tot = torch.zeros_like(tau_c)
        h0 = u_tot
    q0, w0, t0 = state.q_BN, state.omega_B, state.t_s
    half = 0.5 * dt_s
    t_half, t_end = t0 + half, t0 + dt_s
    h_half, h_end = h0 + half * u_tot, h0 + dt_s * u_tot
    k1q, k1w = _rates(q0, w0, h0, tau_c, t0, plant)
    k2q, k2w = _rates(q0 + half * k1q, w0 + half * k1w, h_half, tau_c, t_half, plant)
    k3q, k3w = _rates(q0 + half * k2q, w0 + half * k2w, h_half, tau_c, t_half, plant)
    k4q, k4w = _rates(q0 + dt_s * k3q, w0 + dt_s * k3w, h_end, tau_c, t_end, plant)
    sixth = dt_s / 6.0
    q1 = quat.normalize(q0 + sixth * (k1q + 2 * k2q + 2 * k3q + k4q))
    w1 = w0 + sixth * (k1w + 2 * k2w + 2 * k3w + k4w)
    h1 = state.h_B + dt_s * u if plant.wheels else state.h_B
    return State(q_BN=q1, omega_B=w1, h_B=h1, t_s=t_end), tau_c


PhysicsStep = Callable[[State, Plant, Tensor, float], tuple[State, Tensor]]


def control_step(
    state: State, plant: Plant, tau_cmd_B: Tensor, dt_s: float, frame_skip: int, step: PhysicsStep | None = None
) -> tuple[State, Tensor]:
    """Hold the command (B, K, 3) for ``frame_skip`` physics steps (of ``step``: :func:`physics_step`,
    or :func:`compiled_physics_step`'s fused kernel).

    Returns the new state and the mean body control torque delivered over the interval,
    (B, 3) N m, for effort metrics.
    """
    step = physics_step if step is None else step
    delivered = torch.zeros_like(state.omega_B)
    for _ in range(frame_skip):
        state, tau_c = step(state, plant, tau_cmd_B, dt_s)
        delivered = delivered + tau_c
    return state, delivered / frame_skip


def angular_momentum_N(state: State, plant: Plant) -> Tensor:
    """Total angular momentum (body + wheels) in N components, (B, 3) N m s."""
    H_B = _matvec(plant.I_B, state.omega_B) + state.h_B.sum(dim=1)
    return quat.rotate(state.q_BN, H_B)


def kinetic_energy(state: State, plant: Plant) -> Tensor:
    """Rotational kinetic energy of the body, (B,) J (wheel inertia is not modelled)."""
    return 0.5 * (state.omega_B * _matvec(plant.I_B, state.omega_B)).sum(-1)


_COMPILED: PhysicsStep | None = None


def compiled_physics_step() -> PhysicsStep:
    """:func:`physics_step` fused by ``torch.compile`` (inductor: one C++ kernel per RK4 step on a CPU,
    forward and backward), built once per process. The first call of each new shape compiles (14-18 s
    measured on an AMD EPYC core, minutes on a busy machine; inductor's on-disk cache makes a later
    process's first call faster); the numbers
    agree with :func:`physics_step` to float rounding, not bit for bit (docs/diffsim.md, "Compiled
    physics")."""
    global _COMPILED
    if _COMPILED is None:
        if not has_cxx_compiler():  # inductor builds C++ kernels: without a compiler, fly eager
            warnings.warn(
                "no C++ compiler (g++, or $CXX) found: the physics step flies eager, not compiled", stacklevel=2
            )
            return physics_step
        _COMPILED = cast(PhysicsStep, torch.compile(physics_step, dynamic=None))
    return _COMPILED


def has_cxx_compiler() -> bool:
    """Whether the C++ compiler inductor builds its CPU kernels with (``$CXX``, else g++) is on the PATH."""
    return shutil.which(os.environ.get("CXX") or "g++") is not None
