"""The layers and per-row helpers every actor-critic pair shares (co-design networks of
:mod:`modsat_core.agent.networks`, flat pairs of :mod:`modsat_core.agent.flat_networks`): the MLP, masked
mean pooling over cells, and the per-row terms TD3's actor loss asks an actor for (its
clamp, its torque effort, its design imitation gap).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from modsat_core.codesign.features import CellObs


def mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers with ReLU between them (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def finish(obs: CellObs, action: Tensor) -> Tensor:
    """Clamp a (perturbed) per-cell action to [-1, 1] and zero the cells that do not act."""
    return action.clamp(-1.0, 1.0) * obs.act_mask.unsqueeze(-1)


def effort(obs: CellObs, action: Tensor) -> Tensor:
    """(B,) sum of the squared torque commands of a flying row's acting cells; 0 on design rows
    (their outputs are type choices, not torques). The actor's penalty of `training.action_l2`."""
    return action.square().sum((1, 2)) * (~obs.design).to(action.dtype)


def imitation(obs: CellObs, action: Tensor, behaviour: Tensor) -> tuple[Tensor, Tensor]:
    """(B,) squared distance between a design row's actions and the replay's, summed over the
    three values and averaged over the acting cells, 0 on flying rows; and (B,) bool, the
    design rows. The actor's behaviour-cloning term of `training.design_bc`."""
    gap = (action - behaviour).square().sum(-1)
    mask = obs.act_mask.to(gap.dtype)
    return (gap * mask).sum(1) / mask.sum(1).clamp(min=1.0) * obs.design.to(gap.dtype), obs.design


def masked_mean(t: Tensor, mask: Tensor) -> Tensor:
    """Mean of (B, C, k) over the cells where ``mask`` (B, C) is true (zeros where none is)."""
    w = mask.to(t.dtype)
    w = w / w.sum(dim=1, keepdim=True).clamp(min=1.0)
    return torch.bmm(w.unsqueeze(1), t).squeeze(1)  # one batched product, not a (B, C, k) temporary
