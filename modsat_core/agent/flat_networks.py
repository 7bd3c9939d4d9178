"""Plain MLP actor / critic pairs for flat observations: gymnasium tasks (td3_gym) and the
flat controller of ``bench control``. They follow the protocol of :class:`modsat_core.agent.td3.TD3`.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from modsat_core.agent.layers import mlp
from modsat_core.codesign.features import mirror_control


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
