"""The first-order learner's controller: a small MLP from the satellite's state to its body torque.

It is trained by backpropagating a cost through the simulator (``training/diffsim.py``) and flies
one design. Its inputs, all of the whole satellite (19 numbers, float32):

    q_BT (4, w >= 0), omega_B / rate_limit (3), h_tot_B / (K tau_max) (3),
    tanh(30 q_v) (3), tanh(300 q_v) (3), tanh(50 omega_B / (rad/s)) (3)

and, for a controller that flies many designs (``diffsim.design_pool`` > 0, `diffsim-codesign`),
6 more of the design:

    log(K tau_max / I_ii) (3: the torque-to-inertia ratio of each body axis, 1/s^2),
    I_ij / trace(I) (3: xy, xz, yz, the products of inertia)

``q_BT = conj(q_TN) (x) q_BN`` is the error quaternion (wxyz, Hamilton product), ``h_tot_B`` the
momentum stored in all the wheel units together (N m s; zero with the ideal-torque model), K the
number of wheel units and tau_max the per-axis torque of one. The fine channels resolve the last
hundredths of a degree and of a rad/s, where the mission's tolerance is.

The network's output ``f`` (3, each in (-1, 1)) is a body torque as a fraction of the wheel
units' box ``K tau_max``. It is odd in the state: ``f(x) = tanh((g(x) - g(Mx)) / 2)`` with ``M``
negating everything but ``q_w``, so it is exactly zero at the target and a mirrored state gets the
mirrored torque. With ``diffsim.base`` `pd` (the default) the controller's torque is the design's
PD law plus that correction, ``tau_c_B = clip(tau_PD / (K tau_max) + f, -1, 1) * K tau_max``; with
`none` it is ``f * K tau_max`` alone. Either way it is split equally over the K units (the PD
baseline's allocation; the units are body-aligned, so where they sit does not change the torque).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor, nn

from modsat_core.grid import ACTUATOR
from modsat_core.sim.pd import RATE_GAIN_MAX, PDGains, pd_gains, pd_torque

if TYPE_CHECKING:
    from modsat_core.sim.dynamics import Plant
    from modsat_core.sim.slew import SlewSim

#: Inputs of the network (see the module docstring) ...
N_DIFFSIM_INPUTS = 19
#: ... and the design's, for a design-conditioned controller.
N_DESIGN_INPUTS = 6
#: Name of the network in ``policy.pt``: the network alone (``diffsim.base`` `none`) ...
DIFFSIM_NETWORK = "diffsim-mlp"
#: ... and the network as a correction to the design's PD law (`pd`).
DIFFSIM_PD_NETWORK = "diffsim-pd-residual"


def diffsim_inputs(q_BT: Tensor, omega_B: Tensor, h_tot_B: Tensor, rate_limit_rad_s: float, box_Nm: Tensor) -> Tensor:
    """(B, 19) network inputs from the error quaternion (B, 4), body rate (B, 3) rad/s, total wheel
    momentum (B, 3) N m s and the torque box ``K tau_max`` (B, 1) N m."""
    q = q_BT * torch.where(q_BT[:, :1] < 0, -1.0, 1.0)
    qv = q[:, 1:]
    return torch.cat(
        (
            q,
            omega_B / rate_limit_rad_s,
            h_tot_B / box_Nm,
            torch.tanh(30.0 * qv),
            torch.tanh(300.0 * qv),
            torch.tanh(50.0 * omega_B),
        ),
        dim=-1,
    )


def design_inputs(I_B: Tensor, box_Nm: Tensor) -> Tensor:
    """(B, 6) design inputs from the inertia (B, 3, 3) kg m^2 and the torque box (B, 1) N m."""
    diag = torch.diagonal(I_B, dim1=-2, dim2=-1)
    trace = diag.sum(dim=-1, keepdim=True)
    off = torch.stack((I_B[:, 0, 1], I_B[:, 0, 2], I_B[:, 1, 2]), dim=-1)
    return torch.cat((torch.log(box_Nm / diag), off / trace), dim=-1)


class DiffsimPolicy(nn.Module):
    """``x (B, 19 [+ 6]) -> f (B, 3)``, odd in the state (the design's inputs are even); tanh MLP
    whose last layer starts near zero. ``n_design``: 0 (one design) or :data:`N_DESIGN_INPUTS`."""

    if TYPE_CHECKING:  # the buffer's type, for mypy only: TorchScript cannot read string annotations
        mirror: Tensor

    def __init__(self, hidden_sizes: list[int], n_design: int = 0):
        super().__init__()
        self.n_design = n_design
        layers: list[nn.Module] = []
        width = N_DIFFSIM_INPUTS + n_design
        for h in hidden_sizes:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        last = nn.Linear(width, 3)
        nn.init.uniform_(last.weight, -1e-3, 1e-3)
        nn.init.zeros_(last.bias)
        layers.append(last)
        self.net = nn.Sequential(*layers)
        sign = torch.full((N_DIFFSIM_INPUTS + n_design,), -1.0)
        sign[0] = 1.0  # q_w is even; every other input of the state is odd
        sign[N_DIFFSIM_INPUTS:] = 1.0  # the design is what it is in a mirrored state
        self.register_buffer("mirror", sign)
        # The PD law's delay-margin cap this controller was trained on (``diffsim.base`` `pd`):
        # policy files record it; those written before it was stated flew sim.pd's older cap.
        self.pd_rate_gain_max = RATE_GAIN_MAX

    def forward(self, x: Tensor) -> Tensor:
        return torch.tanh(0.5 * (self.net(x) - self.net(x * self.mirror)))


class DiffsimController:
    """Flies :class:`SlewSim`'s satellites with a :class:`DiffsimPolicy` (on the PD law when ``base``
    is `pd`): ``controller(sim) -> action`` (B, K, 3) in [-1, 1], the same per-unit fraction for every
    wheel unit. Differentiable: the learner calls it with gradients on (through the PD law too);
    :func:`~modsat_core.evaluation.monte_carlo.monte_carlo` without."""

    def __init__(self, policy: DiffsimPolicy, rate_limit_rad_s: float, base: str):
        self.policy, self.rate_limit, self.base = policy, rate_limit_rad_s, base
        weight = next(policy.parameters())
        self.dtype, self.device = weight.dtype, weight.device
        self._plant: Plant | None = None  # the plant whose PD gains are cached
        self._gains: PDGains | None = None

    def gains(self, sim: SlewSim) -> PDGains:
        """PD's gains for the sim's satellites, recomputed when its plant changes."""
        if self._gains is None or self._plant is not sim.plant:
            self._plant, self._gains = sim.plant, pd_gains(sim, rate_gain_max=self.policy.pd_rate_gain_max)
        return self._gains

    def __call__(self, sim: SlewSim) -> Tensor:
        q_BT, st, plant = sim.error_quaternion(), sim.state, sim.plant
        h_tot = st.h_B.sum(dim=1)
        x = diffsim_inputs(q_BT, st.omega_B, h_tot, self.rate_limit, plant.box_Nm)
        if self.policy.n_design:
            x = torch.cat((x, design_inputs(plant.I_B, plant.box_Nm)), dim=-1)
        f = self.policy(x.to(device=self.device, dtype=self.dtype)).to(device=sim.device, dtype=sim.dtype)
        if self.base == "pd":
            g = self.gains(sim)
            tau = pd_torque(q_BT, st.omega_B, h_tot, plant.I_B, g.lam_per_s, g.c_per_s, g.omega_lim_rad_s, plant.box_Nm)
            f = tau / plant.box_Nm + f  # SlewSim clips the action to [-1, 1]
        return f.unsqueeze(1) * plant.slots.unsqueeze(-1).to(sim.dtype)


class ExportedDiffsimController(nn.Module):
    """A :class:`DiffsimPolicy` flying one design, needing only torch: the same interface as the
    TD3 export. ``forward(q_BT, omega_B, h_B)``: error quaternion (B, 4) wxyz, body rate (B, 3)
    rad/s, per-wheel-unit momentum (B, K, 3) N m s -> per-unit body torque command (B, K, 3) N m.
    ``I_B``: the design's inertia (3, 3); with ``pd`` (the design's PD gains, from
    :func:`~modsat_core.sim.pd.pd_gains`) it adds the network's correction to the PD law, as
    :class:`DiffsimController`."""

    if TYPE_CHECKING:  # the buffers' types, for mypy only
        I_B: Tensor
        design: Tensor
        unit_tau: Tensor
        lam: Tensor
        c: Tensor

    def __init__(
        self,
        policy: DiffsimPolicy,
        grid: np.ndarray,
        rate_limit_rad_s: float,
        tau_max_Nm: float,
        I_B: Tensor,
        pd: PDGains | None = None,
        unit_torque_Nm: np.ndarray | None = None,
    ):
        super().__init__()
        self.policy = policy
        self.K = int((np.asarray(grid) >= ACTUATOR).sum())
        self.rate_limit = rate_limit_rad_s
        self.tau_max = tau_max_Nm
        # each wheel unit's per-axis torque (a parts catalog's units differ); the box is their sum
        unit = np.full(self.K, tau_max_Nm) if unit_torque_Nm is None else np.asarray(unit_torque_Nm, dtype=np.float64)
        self.register_buffer("unit_tau", torch.as_tensor(unit, dtype=torch.float64).reshape(1, self.K, 1))
        self.box = float(unit.sum())
        self.residual = pd is not None
        f64 = torch.float64
        I_B = I_B.detach().to(f64).reshape(1, 3, 3)
        self.register_buffer("I_B", I_B[0])
        # the design's inputs (none for a one-design controller), constant for the exported design
        design = design_inputs(I_B, torch.full((1, 1), self.box, dtype=f64))
        self.register_buffer("design", design[:, : policy.n_design].float())
        zero = torch.zeros(1, dtype=f64)
        self.register_buffer("lam", zero if pd is None else pd.lam_per_s.detach().to(f64).reshape(1))
        self.register_buffer("c", zero.clone() if pd is None else pd.c_per_s.detach().to(f64).reshape(1))
        self.omega_lim = 0.0 if pd is None else float(pd.omega_lim_rad_s)

    def forward(self, q_BT: Tensor, omega_B: Tensor, h_B: Tensor) -> Tensor:
        # q and -q are one attitude: the PD law takes the representative the simulator passes
        # (w >= 0), so that it turns the short way whatever sign the caller gives.
        q_BT = q_BT * torch.where(q_BT[:, :1] < 0, -1.0, 1.0)
        box = torch.full((q_BT.shape[0], 1), self.box, dtype=q_BT.dtype)
        h_tot = h_B.sum(dim=1)
        x = diffsim_inputs(q_BT, omega_B, h_tot, self.rate_limit, box).float()
        x = torch.cat((x, self.design.expand(x.shape[0], -1)), dim=-1)
        f = self.policy(x).to(q_BT.dtype)
        if self.residual:
            dt = q_BT.dtype
            tau = pd_torque(q_BT, omega_B, h_tot, self.I_B.to(dt), self.lam.to(dt), self.c.to(dt), self.omega_lim, box)
            f = (tau / box + f).clamp(-1.0, 1.0)
        return f.unsqueeze(1).expand(-1, self.K, 3) * self.unit_tau.to(q_BT.dtype)
