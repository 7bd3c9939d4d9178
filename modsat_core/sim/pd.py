"""Quaternion-feedback PD baseline with rate limit (Wie's rate-limited eigenaxis slew).

    omega_cmd = -sat_{omega_lim}(2 lam q_BT,v)          (norm saturation keeps the eigenaxis)
    tau_c     = c I (omega_cmd - omega_B) + omega_B x (I omega_B + h_B)

Unsaturated this is ``tau_c = -K q_v - C omega + gyro`` with ``K = k I``, ``C = c I``,
``k = 2 lam c``: the classical eigenaxis PD law (Wie, Weiss & Arapostathis 1989). The
command rate is limited to ``omega_lim`` (a margin below the safety limit) as in Wie &
Lu's rate-limited slews, and the torque vector is scaled down, not clipped per axis, so it
keeps its direction when it exceeds the wheel units' box of ``n_act * tau_max`` per axis.
Every wheel unit gets an equal share.

Gains are chosen per design from its torque authority: the decay rate ``lam`` is small
enough that the worst-axis deceleration needed near the target is a quarter of what the
wheels can give, and ``c = 4 lam`` makes the linearised loop critically damped.

Delay margin: the rate loop's gain per control step is capped at ``c T <= 0.42``
(:data:`RATE_GAIN_MAX`). With one control step of actuation delay the sampled rate loop is
``w[k+1] = w[k] - c T w[k-1]``, whose poles ``z = 0.5 +- 0.41i`` (for 0.42) are damped (ratio
0.55): a step of the commanded rate overshoots by about 12 %, so the cruise rate (0.8 of the
limit) stays inside the rate limit. The cap binds only on designs with much torque for their
inertia (several wheel units on a small satellite); measured on the 3-actuator 3x3x3 design, a
cap of 1.0 (the law before the margin was stated, ``c T < 2`` without delay) breaks the rate limit
on 100 of 100 slews with one step of delay, 0.5 on 52, 0.42 on none (docs/robustness.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from modsat_core.sim.dynamics import _matvec
from modsat_core.sim.slew import SlewSim

#: The largest rate-loop gain per control step, ``c T`` (the delay margin; module docstring).
RATE_GAIN_MAX = 0.42
#: The cap before the delay margin was stated (policies trained on that PD law keep it).
RATE_GAIN_MAX_NO_DELAY_MARGIN = 1.0


@dataclass(frozen=True)
class PDGains:
    lam_per_s: Tensor  # (B,) closed-loop decay rate of the error angle far from saturation
    c_per_s: Tensor  # (B,) rate-loop gain (C = c I)
    omega_lim_rad_s: float


def pd_gains(
    sim: SlewSim, rate_margin: float = 0.8, decel_fraction: float = 0.25, rate_gain_max: float = RATE_GAIN_MAX
) -> PDGains:
    """Gains for each satellite of ``sim`` from its inertia and number of wheel units; ``c T`` at most
    ``rate_gain_max``."""
    plant = sim.plant
    omega_lim = rate_margin * sim.mission.rate_limit_rad_s
    I_max = torch.linalg.eigvalsh(plant.I_B)[:, -1]
    alpha = plant.n_actuators.to(sim.dtype) * plant.tau_max_Nm / I_max
    # c = 4 lam: the rate loop's gain per step c T stays under the delay margin's cap.
    lam_max = 0.25 * rate_gain_max / sim.mission.control_dt_s
    lam = torch.clamp(decel_fraction * alpha / omega_lim, max=lam_max)
    return PDGains(lam_per_s=lam, c_per_s=4.0 * lam, omega_lim_rad_s=omega_lim)


def pd_torque(
    q_BT: Tensor,
    omega_B: Tensor,
    h_tot_B: Tensor,
    I_B: Tensor,
    lam_per_s: Tensor,
    c_per_s: Tensor,
    omega_lim_rad_s: float,
    box_Nm: Tensor,
) -> Tensor:
    """The law of the module docstring: body torque (B, 3), N m, scaled into the box ``box_Nm``
    (B, 1) from the error quaternion (B, 4) wxyz, the body rate and total wheel momentum (B, 3),
    the inertia (B, 3, 3) or (3, 3) and the gains (B,) or (1,). Plain tensor code: it also runs
    inside exported controllers (TorchScript)."""
    w_cmd = -2.0 * lam_per_s.unsqueeze(-1) * q_BT[:, 1:]
    norm = w_cmd.norm(p=2, dim=-1, keepdim=True)
    w_cmd = w_cmd * torch.clamp(omega_lim_rad_s / norm.clamp(min=1e-12), max=1.0)
    H_B = _matvec(I_B, omega_B) + h_tot_B
    tau = c_per_s.unsqueeze(-1) * _matvec(I_B, w_cmd - omega_B) + torch.cross(omega_B, H_B, dim=-1)
    scale = torch.clamp((tau.abs() / box_Nm).amax(dim=-1, keepdim=True), min=1.0)
    return tau / scale


class PDController:
    """Callable ``controller(sim) -> action (B, K, 3)`` in [-1, 1] for :class:`SlewSim`."""

    def __init__(self, sim: SlewSim, **gain_kwargs):
        self.gains = pd_gains(sim, **gain_kwargs)

    def torque(self, sim: SlewSim) -> Tensor:
        """Total body torque command (B, 3), N m, inside the wheel units' box."""
        g, plant, st = self.gains, sim.plant, sim.state
        return pd_torque(
            sim.error_quaternion(),
            st.omega_B,
            st.h_B.sum(dim=1),
            plant.I_B,
            g.lam_per_s,
            g.c_per_s,
            g.omega_lim_rad_s,
            plant.box_Nm,
        )

    def __call__(self, sim: SlewSim) -> Tensor:
        plant = sim.plant
        per_unit = self.torque(sim) / plant.box_Nm
        return per_unit.unsqueeze(1) * plant.slots.unsqueeze(-1)
