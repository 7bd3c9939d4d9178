"""The first-order learner's controller: a small MLP from the satellite's state to its body torque.

It is trained by backpropagating a cost through the simulator (``training/diffsim.py``) and flies
one design. Its inputs, all of the whole satellite (19 numbers, float32):

    q_BT (4, w >= 0), omega_B / rate_limit (3), h_tot_B / (K tau_max) (3),
    tanh(30 q_v) (3), tanh(300 q_v) (3), tanh(50 omega_B / (rad/s)) (3)

``q_BT = conj(q_TN) (x) q_BN`` is the error quaternion (wxyz, Hamilton product), ``h_tot_B`` the
momentum stored in all the wheel units together (N m s; zero with the ideal-torque model), K the
number of wheel units and tau_max the per-axis torque of one. The fine channels resolve the last
hundredths of a degree and of a rad/s, where the mission's tolerance is.

Its output ``f`` (3, each in (-1, 1)) is the body torque as a fraction of the wheel units' box:
``tau_c_B = f * K * tau_max``, split equally over the K units (the PD baseline's allocation; the
units are body-aligned, so where they sit does not change the torque). The output is odd in the
state: ``f(x) = tanh((g(x) - g(Mx)) / 2)`` with ``M`` negating everything but ``q_w``, so the
torque is exactly zero at the target and a mirrored state gets the mirrored torque.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor, nn

from modsat_core.grid import ACTUATOR

if TYPE_CHECKING:
    from modsat_core.sim.slew import SlewSim

#: Inputs of the network (see the module docstring).
N_DIFFSIM_INPUTS = 19
#: Name of the network in ``policy.pt``.
DIFFSIM_NETWORK = "diffsim-mlp"


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


class DiffsimPolicy(nn.Module):
    """``x (B, 19) -> f (B, 3)``, odd in the state; tanh MLP whose last layer starts near zero."""

    if TYPE_CHECKING:  # the buffer's type, for mypy only: TorchScript cannot read string annotations
        mirror: Tensor

    def __init__(self, hidden_sizes: list[int]):
        super().__init__()
        layers: list[nn.Module] = []
        width = N_DIFFSIM_INPUTS
        for h in hidden_sizes:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        last = nn.Linear(width, 3)
        nn.init.uniform_(last.weight, -1e-3, 1e-3)
        nn.init.zeros_(last.bias)
        layers.append(last)
        self.net = nn.Sequential(*layers)
        sign = torch.full((N_DIFFSIM_INPUTS,), -1.0)
        sign[0] = 1.0  # q_w is even; every other input is odd in the state
        self.register_buffer("mirror", sign)

    def forward(self, x: Tensor) -> Tensor:
        return torch.tanh(0.5 * (self.net(x) - self.net(x * self.mirror)))


class DiffsimController:
    """Flies :class:`SlewSim`'s satellites with a :class:`DiffsimPolicy`: ``controller(sim) -> action``
    (B, K, 3) in [-1, 1], the same per-unit fraction for every wheel unit. Differentiable: the
    learner calls it with gradients on; :func:`~modsat_core.evaluation.monte_carlo.monte_carlo`
    without."""

    def __init__(self, policy: DiffsimPolicy, rate_limit_rad_s: float):
        self.policy, self.rate_limit = policy, rate_limit_rad_s
        weight = next(policy.parameters())
        self.dtype, self.device = weight.dtype, weight.device

    def __call__(self, sim: SlewSim) -> Tensor:
        x = diffsim_inputs(
            sim.error_quaternion(), sim.state.omega_B, sim.state.h_B.sum(dim=1), self.rate_limit, sim.plant.box_Nm
        )
        f = self.policy(x.to(device=self.device, dtype=self.dtype)).to(device=sim.device, dtype=sim.dtype)
        return f.unsqueeze(1) * sim.plant.actuator_mask.unsqueeze(-1).to(sim.dtype)


class ExportedDiffsimController(nn.Module):
    """A :class:`DiffsimPolicy` flying one design, needing only torch: the same interface as the
    TD3 export. ``forward(q_BT, omega_B, h_B)``: error quaternion (B, 4) wxyz, body rate (B, 3)
    rad/s, per-wheel-unit momentum (B, K, 3) N m s -> per-unit body torque command (B, K, 3) N m."""

    def __init__(self, policy: DiffsimPolicy, grid: np.ndarray, rate_limit_rad_s: float, tau_max_Nm: float):
        super().__init__()
        self.policy = policy
        self.K = int((np.asarray(grid) == ACTUATOR).sum())
        self.rate_limit = rate_limit_rad_s
        self.tau_max = tau_max_Nm

    def forward(self, q_BT: Tensor, omega_B: Tensor, h_B: Tensor) -> Tensor:
        box = torch.full((q_BT.shape[0], 1), self.K * self.tau_max, dtype=q_BT.dtype)
        x = diffsim_inputs(q_BT, omega_B, h_B.sum(dim=1), self.rate_limit, box)
        f = self.policy(x.float())
        return f.unsqueeze(1).expand(-1, self.K, 3) * self.tau_max
