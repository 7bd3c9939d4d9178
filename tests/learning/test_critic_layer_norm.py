"""`training.critic_layer_norm`: LayerNorm before each ReLU of the critics' wide layers."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from modsat_core.agent.flat_networks import MLPCritic
from modsat_core.agent.networks import NETWORKS, make_critic
from modsat_core.codesign.features import N_FEATURES, CellObs
from modsat_core.training.td3_trainer import TD3Run

from .conftest import tiny_spec


def _first_linears(critic: nn.Module) -> list[nn.Linear]:
    """The first Linear layer of every twin's wide stack (q1, q2; per phase where there are two)."""
    return [m.q1[0] for m in critic.modules() if hasattr(m, "q1")] + [
        m.q2[0] for m in critic.modules() if hasattr(m, "q2")
    ]


def _obs(batch: int, cells: int = 8) -> tuple[CellObs, torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    x = torch.randn(batch, cells, N_FEATURES, generator=g)
    act = torch.zeros(batch, cells, dtype=torch.bool)
    act[:, 0] = True
    design = torch.zeros(batch, dtype=torch.bool)
    design[: batch // 4] = True  # both phases in one batch
    act[design] = True
    obs = CellObs(x=x, act_mask=act, value_mask=torch.ones_like(act), design=design)
    return obs, torch.rand(batch, cells, 3, generator=g) * 2 - 1


def _q_after_scaling_the_first_layers(critic: nn.Module, call) -> tuple[torch.Tensor, torch.Tensor]:
    with torch.no_grad():
        before = torch.stack(call(critic))
        for lin in _first_linears(critic):
            lin.weight.mul_(7.0)
            lin.bias.mul_(7.0)
        return before, torch.stack(call(critic))


@pytest.mark.parametrize("network", NETWORKS)
@pytest.mark.parametrize("layer_norm", [False, True])
def test_a_normalised_critic_ignores_the_scale_of_its_first_wide_layer(network, layer_norm):
    # LayerNorm(c z) = LayerNorm(z) for c > 0: with the norm in place, scaling the first
    # wide layer changes no value; without it every value moves.
    torch.manual_seed(0)
    critic = make_critic(network, N_FEATURES, [32, 32], layer_norm)
    obs, action = _obs(16)
    before, after = _q_after_scaling_the_first_layers(critic, lambda c: c(obs, action))
    if layer_norm:
        torch.testing.assert_close(after, before, rtol=1e-4, atol=1e-4)
    else:
        assert (after - before).abs().min() > 1e-3


@pytest.mark.parametrize("layer_norm", [False, True])
def test_the_flat_critic_takes_the_same_switch(layer_norm):
    torch.manual_seed(0)
    critic = MLPCritic(10, 3, [32, 32], layer_norm)
    obs, action = torch.randn(16, 10), torch.rand(16, 3)
    before, after = _q_after_scaling_the_first_layers(critic, lambda c: c(obs, action))
    assert torch.allclose(after, before, rtol=1e-4, atol=1e-4) == layer_norm


def test_the_training_key_reaches_the_run_s_critic():
    run = TD3Run(tiny_spec(training__network="set", training__critic_layer_norm=True))
    norms = [m for m in run.agent.critic.modules() if isinstance(m, nn.LayerNorm)]
    assert len(norms) == 2 * 2 * 2  # two phases x two twins x two hidden layers
    assert not any(isinstance(m, nn.LayerNorm) for m in TD3Run(tiny_spec()).agent.critic.modules())
