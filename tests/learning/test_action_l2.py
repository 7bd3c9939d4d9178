"""`training.action_l2`: the actor's penalty on its squared torque commands (HER's action_l2)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from modsat_core.agent.flat_networks import MLPActor
from modsat_core.agent.layers import effort
from modsat_core.agent.td3 import TD3, TD3Config
from modsat_core.codesign.features import CellObs
from modsat_core.spec.jobspec import Training


class _FlatCritic(nn.Module):
    """Q independent of the action: the only pull on the actor is the penalty."""

    def __init__(self):
        super().__init__()
        self.w = nn.Linear(4, 1)

    def forward(self, obs: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        q = self.w(obs).squeeze(-1) + 0.0 * action.sum(-1)
        return q, q


def _mean_abs_action_after_updates(action_l2: float) -> tuple[float, float]:
    torch.manual_seed(0)
    actor = MLPActor(4, 3, [16])
    with torch.no_grad():
        actor.net[-1].bias.fill_(1.0)  # start well away from zero
    agent = TD3(actor, _FlatCritic(), TD3Config(policy_delay=1, actor_lr=1e-2, action_l2=action_l2))
    obs = torch.randn(64, 4)
    before = actor(obs).abs().mean().item()
    gen = torch.Generator().manual_seed(0)
    for _ in range(50):
        agent.update(obs, actor(obs).detach(), torch.zeros(64), obs, torch.zeros(64, dtype=torch.bool), gen)
    return before, actor(obs).abs().mean().item()


def test_the_penalty_pulls_actions_toward_zero_and_is_off_by_default():
    before, after = _mean_abs_action_after_updates(1.0)
    assert after < 0.5 * before
    before, after = _mean_abs_action_after_updates(0.0)
    assert after == before  # no gradient on the actor at all
    assert Training().action_l2 == 0.0 and TD3Config.from_training(Training()).action_l2 == 0.0


def test_cell_effort_counts_flying_rows_only():
    B, C = 3, 27
    action = torch.zeros(B, C, 3)
    action[:, 13] = torch.tensor([0.5, -1.0, 0.0])  # the actuator cell's torques
    action[:, 4] = 1.0  # a second acting cell: counted on flying rows, not on the design row
    obs = CellObs(
        x=torch.zeros(B, C, 1),
        act_mask=torch.ones(B, C, dtype=torch.bool),
        value_mask=torch.ones(B, C, dtype=torch.bool),
        design=torch.tensor([True, False, False]),
    )
    assert effort(obs, action).tolist() == [0.0, 4.25, 4.25]
