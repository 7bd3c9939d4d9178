"""Using a trained co-design actor: its design, its controller, and a standalone export."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, cast

import numpy as np
import torch
from torch import Tensor, nn

from modsat_core.agent.diffsim_policy import DiffsimController, DiffsimPolicy, ExportedDiffsimController
from modsat_core.agent.networks import CellActor, SetActor, observes_last_command
from modsat_core.codesign.features import (
    CONTROL_AT,
    N_CONTROL_GLOBAL,
    CellObs,
    PhysState,
    cell_observation,
    control_globals,
)
from modsat_core.codesign.mdp import seed_grid
from modsat_core.grid import ACTUATOR
from modsat_core.sim.morphology import seed_component_batched
from modsat_core.sim.pd import pd_gains
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import DesignSpace, JobSpec, Mission, ModuleCatalog


@torch.no_grad()
def design_with(actor: nn.Module, design_space: DesignSpace, mission: Mission) -> np.ndarray:
    """The grid the deterministic NCA grows from the seed module in ``design_steps`` steps."""
    N, D = design_space.grid_size, design_space.design_steps
    grid = torch.as_tensor(seed_grid(N)).unsqueeze(0)
    phys = PhysState(torch.zeros(1, 4), torch.zeros(1, 4), torch.zeros(1, 3), torch.zeros(1, N**3, 3))
    last = torch.zeros(1, N**3, 3) if observes_last_command(actor) else None  # zero features while designing
    for d in range(D):
        obs = cell_observation(grid, torch.tensor([d]), D, phys, mission.rate_limit_rad_s, last)
        grid = actor(obs).argmax(dim=-1).reshape(1, N, N, N)
    if design_space.repair:
        grid = seed_component_batched(grid)
    return grid[0].numpy().astype(np.int64)


class PolicyController:
    """Flies a fixed design with the actor's control head, for :func:`monte_carlo`.

    The Monte-Carlo simulator packs wheel units in row-major cell order, the same order
    as the actor's cells, so unit k is the k-th actuator cell. The observation is the design
    phase's last step (``design_space.design_steps``: the design is done) and the mission's
    rate limit scales the body rate, as in training.

    An actor that observes its last command (`training.observe_last_command`) is given the action
    this controller returned at the previous call, as in training: its own command, before any
    delay or weakening of a flight condition. A row whose simulator has not stepped yet
    (``sim.steps == 0``: a new slew) gets none (zero), so one controller flies any number of
    Monte-Carlo sets one after another.
    """

    def __init__(self, actor: nn.Module, grid: np.ndarray, design_space: DesignSpace, mission: Mission):
        self.actor = actor
        self.design_steps, self.rate_limit_rad_s = design_space.design_steps, mission.rate_limit_rad_s
        self.grid = torch.as_tensor(np.asarray(grid), dtype=torch.long)
        self.N = self.grid.shape[0]
        self.act_cells = torch.as_tensor(np.flatnonzero(np.asarray(grid).reshape(-1) >= ACTUATOR))
        self.last_command = observes_last_command(actor)
        self.last: Tensor | None = None  # (B, C, 3) the previous call's action, where observed

    def _last(self, sim: SlewSim) -> Tensor:
        B, C = sim.B, self.N**3
        if self.last is None or self.last.shape[0] != B:
            return torch.zeros(B, C, 3)
        started = (sim.steps.cpu() > 0).reshape(B, 1, 1)
        return self.last * started.to(self.last.dtype)

    def observation(self, sim: SlewSim) -> CellObs:
        B, C = sim.B, self.N**3
        h_cells = torch.zeros(B, C, 3)
        h_cells[:, self.act_cells] = (sim.state.h_B / sim.h_scale_Nms).float()
        phys = PhysState(sim.state.q_BN.float(), sim.q_TN.float(), sim.state.omega_B.float(), h_cells)
        grids = self.grid.expand(B, self.N, self.N, self.N)
        D = self.design_steps
        last = self._last(sim) if self.last_command else None
        return cell_observation(grids, torch.full((B,), D), D, phys, self.rate_limit_rad_s, last)

    def __call__(self, sim: SlewSim) -> Tensor:
        with torch.no_grad():
            a = self.actor(self.observation(sim))
        if self.last_command:
            self.last = a.detach().float().cpu()
        return a[:, self.act_cells].to(sim.dtype)


class _Exported(nn.Module):
    """What both exported TD3 controllers share: the design's constant per-cell features baked in
    as buffers, and the state's features (:meth:`features`). No branch or shape depends on the data,
    so torch.export and ONNX capture them whole (docs/export.md)."""

    if TYPE_CHECKING:  # the buffers' types, for mypy only: TorchScript cannot read string annotations
        base_x: Tensor
        occupied: Tensor
        act_cells: Tensor
        value_mask: Tensor

    def __init__(
        self, actor: nn.Module, grid: np.ndarray, design_space: DesignSpace, mission: Mission, modules: ModuleCatalog
    ):
        super().__init__()
        N = np.asarray(grid).shape[0]
        C = N**3
        ctrl = PolicyController(actor, grid, design_space, mission)
        # Constant part of the per-cell features: everything but the state-dependent slots.
        probe = PhysState(
            torch.tensor([[1.0, 0, 0, 0]]), torch.tensor([[1.0, 0, 0, 0]]), torch.zeros(1, 3), torch.zeros(1, C, 3)
        )
        D = design_space.design_steps
        base = cell_observation(ctrl.grid.unsqueeze(0), torch.tensor([D]), D, probe, mission.rate_limit_rad_s)
        self.register_buffer("base_x", base.x[0].clone())
        self.register_buffer("occupied", (ctrl.grid.reshape(-1) != 0).float().unsqueeze(-1))
        self.register_buffer("act_cells", ctrl.act_cells.clone())
        self.register_buffer("value_mask", (ctrl.grid.reshape(-1) != 0).unsqueeze(0))
        self.c0 = CONTROL_AT
        self.n_glob = N_CONTROL_GLOBAL
        self.rate_limit = mission.rate_limit_rad_s
        self.tau_max = modules.torque_scale_Nm
        cap = modules.momentum_capacity_Nms
        self.h_scale = cap if cap is not None else modules.torque_scale_Nm
        self.actor = cast("CellActor | SetActor", actor)  # what make_actor builds; forward calls its .act

    def features(self, q_BT: Tensor, omega_B: Tensor, h_B: Tensor) -> Tensor:
        """(B, C, 53) every cell's features in the state (q_BT, omega_B, h_B)."""
        B = q_BT.shape[0]
        C = self.base_x.shape[0]
        q = q_BT * torch.where(q_BT[:, :1] < 0, -1.0, 1.0)
        glob = control_globals(q, omega_B, self.rate_limit)
        x = self.base_x.unsqueeze(0).repeat(B, 1, 1)
        h_cells = torch.zeros(B, C, 3, dtype=x.dtype)
        h_cells[:, self.act_cells] = h_B.to(x.dtype) / self.h_scale
        g0, g1 = self.c0, self.c0 + self.n_glob
        x[:, :, g0:g1] = glob.unsqueeze(1).to(x.dtype) * self.occupied
        x[:, :, g1 : g1 + 3] = h_cells * self.occupied
        return x

    def command(self, x: Tensor) -> Tensor:
        """(B, K, 3) the per-unit body torque command, N m, of the cells' features ``x``."""
        C = x.shape[1]
        a = self.actor.control_on(x, self.value_mask.expand(x.shape[0], C), self.act_cells)
        return a * self.tau_max


class ExportedController(_Exported):
    """A designed satellite's controller as a function of its state, needing only torch.

    ``forward(q_BT, omega_B, h_B)``: error quaternion (B, 4) wxyz, body rate (B, 3) rad/s,
    per-wheel-unit momentum (B, K, 3) N m s -> per-unit body torque command (B, K, 3) N m.
    """

    def forward(self, q_BT: Tensor, omega_B: Tensor, h_B: Tensor) -> Tensor:
        return self.command(self.features(q_BT, omega_B, h_B))


class ExportedLastCommandController(_Exported):
    """The controller of an actor that observes its last command (`training.observe_last_command`).

    ``forward(q_BT, omega_B, h_B, tau_last_B)``: as :class:`ExportedController`'s, and ``tau_last_B``
    (B, K, 3) N m, the command this controller returned at the previous control step (zeros at the
    first step of a slew). It keeps no memory itself (an ONNX graph has none): the caller feeds its
    output back (docs/export.md).
    """

    def forward(self, q_BT: Tensor, omega_B: Tensor, h_B: Tensor, tau_last_B: Tensor) -> Tensor:
        x = self.features(q_BT, omega_B, h_B)
        B, C = x.shape[0], x.shape[1]
        a_last = tau_last_B.to(x.dtype) / self.tau_max  # the actions in [-1, 1] it came from
        own = x.new_zeros(B, C, 3)
        own[:, self.act_cells] = a_last
        mean = a_last.mean(dim=1).unsqueeze(1) * self.occupied  # (B, C, 3): on every module
        return self.command(torch.cat((x, own, mean), dim=-1))


def controller_for(actor: nn.Module, grid: np.ndarray, spec: JobSpec) -> Callable[[SlewSim], Tensor]:
    """What flies ``grid`` with ``actor`` in :func:`~modsat_core.evaluation.monte_carlo.monte_carlo`:
    the first-order learner's controller or the co-design actor's control head."""
    if isinstance(actor, DiffsimPolicy):
        return DiffsimController(actor, spec.mission.rate_limit_rad_s, spec.diffsim.base)
    return PolicyController(actor, grid, spec.design, spec.mission)


def exported(actor: nn.Module, grid: np.ndarray, spec: JobSpec) -> nn.Module:
    """The standalone controller of ``actor`` flying ``grid``: ``forward(q_BT, omega_B, h_B)``, and
    ``tau_last_B`` last where the actor observes its last command."""
    if isinstance(actor, DiffsimPolicy):
        design = Design.from_grid(grid, spec.modules)
        sim = SlewSim.from_designs([design], spec.mission, spec.modules)
        # the design's PD law, as training flew it
        pd = pd_gains(sim, rate_gain_max=actor.pd_rate_gain_max) if spec.diffsim.base == "pd" else None
        tau = spec.modules.torque_scale_Nm
        unit = design.slot_weights()[0] * tau if spec.modules.wheels else None
        return ExportedDiffsimController(actor, grid, spec.mission.rate_limit_rad_s, tau, sim.plant.I_B[0], pd, unit)
    if observes_last_command(actor):
        return ExportedLastCommandController(actor, grid, spec.design, spec.mission, spec.modules)
    return ExportedController(actor, grid, spec.design, spec.mission, spec.modules)
