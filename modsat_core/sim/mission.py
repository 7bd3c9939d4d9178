"""The slew mission: episode draws, reward with safety constraint, time-optimal bound.

Pure functions; the batched simulator in :mod:`modsat_core.sim.slew` uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from modsat_core.sim import quaternion as quat
from modsat_core.spec.jobspec import Mission, RewardSpec

IDENTITY_WXYZ = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass(frozen=True)
class EpisodeDraw:
    """Everything random about one episode (float64 numpy)."""

    q_BN: np.ndarray  # (4,) initial attitude
    q_TN: np.ndarray  # (4,) target attitude
    omega_B: np.ndarray  # (3,) initial body rate, rad/s
    tau_residual_B: np.ndarray  # (3,) constant disturbance torque, N m
    orbit_phase_rad: float


def _unit_quaternion(value, name: str) -> np.ndarray:
    q = np.asarray(value, dtype=np.float64).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(f"{name} must be 4 finite numbers (w, x, y, z); got {value!r}")
    n = np.linalg.norm(q)
    if not 0.5 < n < 2.0:
        raise ValueError(f"{name} must be a unit quaternion (w, x, y, z); its norm is {n:.3g}")
    return q / n


def draw_episode(rng: np.random.Generator, mission: Mission, options: dict | None = None) -> EpisodeDraw:
    """Draw one episode; ``options`` may fix ``q_BN``, ``q_TN`` (wxyz) and ``omega_B``.

    The default start is at rest at the identity attitude; the target is a rotation of
    the initial attitude about a uniformly random axis (body frame) by an angle uniform
    in [slew_min_deg, slew_max_deg]. The draws happen in a fixed order whatever the
    options, so a seed gives the same disturbances with or without them.
    """
    options = dict(options or {})
    unknown = set(options) - {"q_BN", "q_TN", "omega_B"}
    if unknown:
        raise ValueError(f"unknown reset option(s) {sorted(unknown)}; allowed: q_BN, q_TN, omega_B")
    axis = quat.random_axes(rng, 1)[0]
    angle = rng.uniform(mission.slew_min_deg, mission.slew_max_deg) * quat.DEG
    tau_res = (
        np.asarray(mission.residual_torque_Nm, dtype=np.float64)
        + rng.normal(0.0, 1.0, size=3) * mission.residual_torque_std_Nm
    )
    phase = rng.uniform(0.0, 2.0 * math.pi)

    q_BN = _unit_quaternion(options["q_BN"], "q_BN") if "q_BN" in options else IDENTITY_WXYZ.copy()
    if "q_TN" in options:
        q_TN = _unit_quaternion(options["q_TN"], "q_TN")
    else:
        dq = quat.axis_angle_np(axis, np.array(angle))
        q_TN = quat.multiply(torch.from_numpy(q_BN), torch.from_numpy(dq)).numpy()
    omega = np.zeros(3)
    if "omega_B" in options:
        omega = np.asarray(options["omega_B"], dtype=np.float64).reshape(-1)
        if omega.shape != (3,) or not np.all(np.isfinite(omega)):
            raise ValueError(f"omega_B must be 3 finite numbers (rad/s); got {options['omega_B']!r}")
    return EpisodeDraw(q_BN=q_BN, q_TN=q_TN, omega_B=omega, tau_residual_B=tau_res, orbit_phase_rad=phase)


def error_quaternion(q_TN: Tensor, q_BN: Tensor) -> Tensor:
    """Attitude of B relative to the target T, ``q_BT = conj(q_TN) (x) q_BN``, canonical sign."""
    return quat.canonical(quat.multiply(quat.conjugate(q_TN), q_BN))


def reward(
    phi_rad: Tensor,
    phi_prev_rad: Tensor,
    omega_norm: Tensor,
    mission: Mission,
    steps_left: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Per-step reward (Elkins et al. 2020) and safety violation.

    ``exp(-phi / scale)``, minus ``no_progress_penalty`` when phi did not decrease (outside the
    tolerance cone only, unless ``no_progress_penalty_in_tolerance``), plus
    ``in_tolerance_bonus`` while phi <= tolerance (and, with ``bonus_needs_settled``, the rate
    <= ``rate_tolerance_rad_s``), plus ``settle_bonus * exp(-|omega| / settle_rate_scale_rad_s)`` while
    phi <= tolerance, minus ``rate_margin_penalty`` times how far the rate is into the margin below
    the limit (from ``rate_margin_fraction`` of it); a rate above the limit ends the episode
    with ``-safety_penalty`` (minus ``safety_penalty_per_remaining_step`` for each of the
    ``steps_left`` control steps it had left). Returns (reward, in_cone, violated), each (B,).
    """
    r: RewardSpec = mission.reward
    tol = mission.tolerance_deg * quat.DEG
    in_tol = phi_rad <= tol
    rew = torch.exp(-phi_rad / r.error_scale_rad)
    no_progress = phi_rad >= phi_prev_rad
    if not r.no_progress_penalty_in_tolerance:
        no_progress = no_progress & ~in_tol
    rew = rew - r.no_progress_penalty * no_progress.to(rew.dtype)
    bonus = in_tol & (omega_norm <= mission.rate_tolerance_rad_s) if r.bonus_needs_settled else in_tol
    rew = rew + r.in_tolerance_bonus * bonus.to(rew.dtype)
    if r.settle_bonus:
        rew = rew + r.settle_bonus * in_tol.to(rew.dtype) * torch.exp(-omega_norm / r.settle_rate_scale_rad_s)
    if r.rate_margin_penalty:
        start = r.rate_margin_fraction * mission.rate_limit_rad_s
        used = ((omega_norm - start) / (mission.rate_limit_rad_s - start)).clamp(min=0.0)
        rew = rew - r.rate_margin_penalty * used.to(rew.dtype)
    violated = omega_norm > mission.rate_limit_rad_s
    penalty = torch.full_like(rew, -r.safety_penalty)
    if steps_left is not None and r.safety_penalty_per_remaining_step:
        penalty = penalty - r.safety_penalty_per_remaining_step * steps_left.to(rew.dtype)
    rew = torch.where(violated, penalty, rew)
    return rew, in_tol, violated


def return_bounds(mission: Mission) -> tuple[float, float]:
    """The lowest and highest return any episode on a valid design can get."""
    r = mission.reward
    per_step_min = -r.no_progress_penalty  # exp(.) > 0
    T = mission.episode_steps
    # A violation at step k: k - 1 steps of at least per_step_min, then the penalty.
    worst_violation = -r.safety_penalty + (T - 1) * min(per_step_min, -r.safety_penalty_per_remaining_step)
    low = min(worst_violation, T * per_step_min)
    high = mission.episode_steps * (1.0 + r.in_tolerance_bonus + r.settle_bonus)
    return low, high


def eigenaxis_bound_s(theta_rad: Tensor, I_axis_kgm2: Tensor, tau_axis_Nm: Tensor, omega_max_rad_s: float) -> Tensor:
    """Rest-to-rest time-optimal eigenaxis slew time under torque and rate limits.

    Bang-bang ``2 sqrt(theta I / tau)``; when the peak rate ``sqrt(theta tau / I)`` would
    exceed ``omega_max``, bang-coast-bang ``theta / omega_max + I omega_max / tau``.
    """
    alpha = tau_axis_Nm / I_axis_kgm2
    bang = 2.0 * torch.sqrt(theta_rad / alpha)
    coast = theta_rad / omega_max_rad_s + omega_max_rad_s / alpha
    return torch.where(theta_rad * alpha > omega_max_rad_s**2, coast, bang)


def slew_axis_properties(
    q_BT0: Tensor, I_B: Tensor, n_actuators: Tensor, tau_max_Nm: float
) -> tuple[Tensor, Tensor, Tensor]:
    """Initial error angle, inertia about the eigenaxis and the largest torque about it.

    The wheel units' per-axis limits make the available torque a box of half-width
    ``n_act * tau_max``; its largest component along the unit axis e is
    ``n_act * tau_max * |e|_1``. Returns (theta (B,), I_axis (B,), tau_axis (B,)).
    """
    v = q_BT0[..., 1:]
    norm = v.norm(dim=-1, keepdim=True)
    e = torch.where(norm > 1e-12, v / norm.clamp(min=1e-12), torch.zeros_like(v))
    e = torch.where(norm > 1e-12, e, torch.tensor([1.0, 0.0, 0.0], dtype=v.dtype, device=v.device))
    theta = quat.error_angle(q_BT0)
    I_axis = (e * (I_B * e.unsqueeze(-2)).sum(-1)).sum(-1)
    tau_axis = n_actuators.to(v.dtype) * tau_max_Nm * e.abs().sum(-1)
    return theta, I_axis, tau_axis
