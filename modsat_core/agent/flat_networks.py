"""Plain MLP actor / critic pairs for flat observations (gymnasium tasks, td3_gym), and the flat
controller of ``bench control``: the same MLPs on one fixed design's per-cell observations, so
that the co-design trainer trains it. All follow the protocol of :class:`modsat_core.agent.td3.TD3`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from modsat_core.agent.layers import effort, finish, imitation, mlp
from modsat_core.codesign.features import CONTROL_AT, N_CONTROL_GLOBAL, CellObs, mirror_control
from modsat_core.grid import ACTUATOR


class MLPActor(nn.Module):
    """Deterministic actor for flat observations; actions in [-1, 1]^act_dim.

    ``mirror_at`` (optional): the observation holds :func:`~modsat_core.codesign.features.control_globals`
    there, and the actor is made odd under :func:`~modsat_core.codesign.features.mirror_control`:
    ``tanh((net(o) - net(mirror(o))) / 2)``, so the torque of the mirrored state is the negated
    torque, and exactly zero for a pointed, still satellite (`training.odd_control`).
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: list[int], mirror_at: int | None = None):
        super().__init__()
        self.net = mlp([obs_dim, *hidden, act_dim])
        self.mirror_at = mirror_at

    def forward(self, obs: Tensor) -> Tensor:
        if self.mirror_at is None:
            return torch.tanh(self.net(obs))
        return torch.tanh(0.5 * (self.net(obs) - self.net(mirror_control(obs, self.mirror_at))))

    @staticmethod
    def finish(obs: Tensor, action: Tensor) -> Tensor:
        return action.clamp(-1.0, 1.0)

    @staticmethod
    def effort(obs: Tensor, action: Tensor) -> Tensor:
        """(B,) sum of the squared actions of each row (`training.action_l2`)."""
        return action.square().sum(-1)

    @staticmethod
    def imitation(obs: Tensor, action: Tensor, behaviour: Tensor) -> tuple[Tensor, Tensor]:
        """(B,) zeros and no rows: the flat controller has no design actions (`training.design_bc`)."""
        zero = action.new_zeros(action.shape[0])
        return zero, zero.bool()


class MLPCritic(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, hidden: list[int]):
        super().__init__()
        self.q1 = mlp([obs_dim + act_dim, *hidden, 1])
        self.q2 = mlp([obs_dim + act_dim, *hidden, 1])

    def forward(self, obs: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        xa = torch.cat((obs, action), dim=-1)
        return self.q1(xa).squeeze(-1), self.q2(xa).squeeze(-1)


def flat_observation(obs: CellObs, act_cells: Tensor) -> Tensor:
    """(B, 20 + 3K) the satellite's flat state in a fixed design's per-cell observations: the
    control globals (the same on every cell; read on the first actuator) and each actuator
    cell's wheel momentum, in cell order (the simulator's wheel-unit order)."""
    g0, g1 = CONTROL_AT, CONTROL_AT + N_CONTROL_GLOBAL
    glob = obs.x[:, act_cells[0], g0:g1]
    h = obs.x[:, act_cells, g1 : g1 + 3].reshape(obs.x.shape[0], -1)
    return torch.cat((glob, h), dim=-1)


def _actuator_cells(grid: np.ndarray) -> Tensor:
    cells = np.flatnonzero(np.asarray(grid).reshape(-1) >= ACTUATOR)
    if len(cells) == 0:
        raise ValueError("the flat controller needs a design with at least one actuator")
    return torch.as_tensor(cells)


class FlatCellActor(nn.Module):
    """The flat controller of one fixed design as a co-design actor: :class:`MLPActor` on
    :func:`flat_observation`, its 3K torques put on the actuator cells (zero elsewhere), so the
    trainer, TD3 and the Monte-Carlo's policy controller fly it as they fly the per-cell actors.
    No design head: the design is fixed (``odd_control``: see :class:`MLPActor`)."""

    act_cells: Tensor

    def __init__(self, grid: np.ndarray, hidden: list[int], odd_control: bool = False):
        super().__init__()
        self.register_buffer("act_cells", _actuator_cells(grid))
        k = len(self.act_cells)
        self.mlp = MLPActor(N_CONTROL_GLOBAL + 3 * k, 3 * k, hidden, mirror_at=0 if odd_control else None)

    def forward(self, obs: CellObs) -> Tensor:
        B, C = obs.x.shape[:2]
        a = self.mlp(flat_observation(obs, self.act_cells)).reshape(B, -1, 3)
        return a.new_zeros(B, C, 3).index_copy(1, self.act_cells, a)

    finish = staticmethod(finish)
    effort = staticmethod(effort)
    imitation = staticmethod(imitation)


class FlatCellCritic(nn.Module):
    """The twin critics that go with :class:`FlatCellActor`: :class:`MLPCritic` on the flat
    state and the actuator cells' torques."""

    act_cells: Tensor

    def __init__(self, grid: np.ndarray, hidden: list[int]):
        super().__init__()
        self.register_buffer("act_cells", _actuator_cells(grid))
        k = len(self.act_cells)
        self.mlp = MLPCritic(N_CONTROL_GLOBAL + 3 * k, 3 * k, hidden)

    def forward(self, obs: CellObs, action: Tensor) -> tuple[Tensor, Tensor]:
        a = action[:, self.act_cells].reshape(action.shape[0], -1)
        return self.mlp(flat_observation(obs, self.act_cells), a)
