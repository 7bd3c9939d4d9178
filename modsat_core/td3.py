"""TD3 (Fujimoto et al. 2018): networks, replay buffer and the update, as plain pieces.

The update is one function over any actor/critic pair that follows a small protocol:
``actor(obs) -> action`` and ``actor.finish(obs, action)`` (clamp and mask a perturbed
action), ``critic(obs, action) -> (q1, q2)`` each (B,). The co-design networks
(per-module, masked) and a plain MLP pair for standard gymnasium tasks both follow it, so
the same update is checked on ``Pendulum-v1`` by the tests.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .features import CellObs


def mlp(sizes: list[int]) -> nn.Sequential:
    """Linear layers with ReLU between them (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


# ----------------------------------------------------------------------------- networks


class CellActor(nn.Module):
    """Shared trunk over per-cell features, a design head and a control head (paper Fig. 6)."""

    def __init__(self, n_features: int, hidden: list[int]):
        super().__init__()
        self.trunk = nn.Sequential(mlp([n_features, *hidden]), nn.ReLU())
        self.design_head = nn.Linear(hidden[-1], 3)
        self.control_head = nn.Linear(hidden[-1], 3)

    def forward(self, obs: CellObs) -> Tensor:
        """(B, C, 3) actions in [-1, 1], zero on cells whose action has no effect."""
        z = self.trunk(obs.x)
        raw = torch.where(obs.design.reshape(-1, 1, 1), self.design_head(z), self.control_head(z))
        return torch.tanh(raw) * obs.act_mask.unsqueeze(-1)

    @staticmethod
    def finish(obs: CellObs, action: Tensor) -> Tensor:
        return action.clamp(-1.0, 1.0) * obs.act_mask.unsqueeze(-1)


class CellCritic(nn.Module):
    """Twin per-module critics; a satellite's value is the masked mean over its cells.

    Each cell's critic sees its features, its own action and the mean action of the cells
    whose actions act (the satellite's net command, per actuator). Without the last part
    only the actuator cells' values depend on the action at all: with one actuator in 27
    modules, 26/27 of the value would be blind to control and the actor's gradient
    diluted as much (docs/learning.md).
    """

    def __init__(self, n_features: int, hidden: list[int]):
        super().__init__()
        self.q1 = mlp([n_features + 6, *hidden, 1])
        self.q2 = mlp([n_features + 6, *hidden, 1])

    def forward(self, obs: CellObs, action: Tensor) -> tuple[Tensor, Tensor]:
        m = obs.act_mask.unsqueeze(-1).to(action.dtype)
        mean_a = (action * m).sum(dim=1) / m.sum(dim=1).clamp(min=1.0)
        xa = torch.cat((obs.x, action, mean_a.unsqueeze(1).expand_as(action)), dim=-1)
        w = obs.value_mask.to(xa.dtype)
        denom = w.sum(dim=1).clamp(min=1.0)
        q1 = (self.q1(xa).squeeze(-1) * w).sum(dim=1) / denom
        q2 = (self.q2(xa).squeeze(-1) * w).sum(dim=1) / denom
        return q1, q2


class MLPActor(nn.Module):
    """Deterministic actor for flat observations; actions in [-1, 1]^act_dim."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: list[int]):
        super().__init__()
        self.net = mlp([obs_dim, *hidden, act_dim])

    def forward(self, obs: Tensor) -> Tensor:
        return torch.tanh(self.net(obs))

    @staticmethod
    def finish(obs: Tensor, action: Tensor) -> Tensor:
        return action.clamp(-1.0, 1.0)


class MLPCritic(nn.Module):
    def __init__(self, obs_dim: int, act_dim: int, hidden: list[int]):
        super().__init__()
        self.q1 = mlp([obs_dim + act_dim, *hidden, 1])
        self.q2 = mlp([obs_dim + act_dim, *hidden, 1])

    def forward(self, obs: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        xa = torch.cat((obs, action), dim=-1)
        return self.q1(xa).squeeze(-1), self.q2(xa).squeeze(-1)


# ----------------------------------------------------------------------------- update


@dataclass(frozen=True)
class TD3Config:
    gamma: float = 0.99
    tau: float = 0.005
    policy_noise: float = 0.2
    noise_clip: float = 0.5
    policy_delay: int = 2
    actor_lr: float = 3e-4
    critic_lr: float = 3e-3


class TD3:
    """Online and target networks, their optimisers, and the update counter."""

    def __init__(self, actor: nn.Module, critic: nn.Module, cfg: TD3Config):
        self.cfg = cfg
        self.actor, self.critic = actor, critic
        self.actor_target, self.critic_target = copy.deepcopy(actor), copy.deepcopy(critic)
        for p in (*self.actor_target.parameters(), *self.critic_target.parameters()):
            p.requires_grad_(False)
        self.actor_opt = torch.optim.Adam(actor.parameters(), lr=cfg.actor_lr)
        self.critic_opt = torch.optim.Adam(critic.parameters(), lr=cfg.critic_lr)
        self.updates = 0

    def update(self, obs, action: Tensor, reward: Tensor, next_obs, terminal: Tensor,
               generator: torch.Generator) -> dict[str, float]:
        """One TD3 step on a batch; the actor and targets move every ``policy_delay`` calls."""
        cfg = self.cfg
        with torch.no_grad():
            next_a = self.actor_target(next_obs)
            noise = torch.randn(next_a.shape, generator=generator, device=next_a.device) * cfg.policy_noise
            next_a = self.actor_target.finish(next_obs, next_a + noise.clamp(-cfg.noise_clip, cfg.noise_clip))
            q1_t, q2_t = self.critic_target(next_obs, next_a)
            y = reward + cfg.gamma * (1.0 - terminal.to(reward.dtype)) * torch.minimum(q1_t, q2_t)
        q1, q2 = self.critic(obs, action)
        critic_loss = nn.functional.mse_loss(q1, y) + nn.functional.mse_loss(q2, y)
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()
        self.updates += 1
        info = {"critic_loss": critic_loss.item(), "q": q1.mean().item()}
        if self.updates % cfg.policy_delay == 0:
            actor_loss = -self.critic(obs, self.actor(obs))[0].mean()
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            self.actor_opt.step()
            soft_update(self.actor_target, self.actor, cfg.tau)
            soft_update(self.critic_target, self.critic, cfg.tau)
            info["actor_loss"] = actor_loss.item()
        return info

    def state_dict(self) -> dict:
        return {
            "actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
            "actor_target": self.actor_target.state_dict(), "critic_target": self.critic_target.state_dict(),
            "actor_opt": self.actor_opt.state_dict(), "critic_opt": self.critic_opt.state_dict(),
            "updates": self.updates,
        }

    def load_state_dict(self, d: dict) -> None:
        for name in ("actor", "critic", "actor_target", "critic_target", "actor_opt", "critic_opt"):
            getattr(self, name).load_state_dict(d[name])
        self.updates = d["updates"]


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging ``target <- tau source + (1 - tau) target``."""
    for t, s in zip(target.parameters(), source.parameters()):
        t.lerp_(s, tau)


# ----------------------------------------------------------------------------- buffer


class ReplayBuffer:
    """A ring buffer of named tensors, each stored in the dtype it was declared with."""

    def __init__(self, fields: dict[str, tuple[tuple[int, ...], torch.dtype]], capacity: int, device="cpu"):
        self.capacity = capacity
        self.data = {k: torch.zeros((capacity, *shape), dtype=dt, device=device) for k, (shape, dt) in fields.items()}
        self.pos = 0
        self.size = 0

    @property
    def nbytes(self) -> int:
        """Bytes the buffer holds when full (it is allocated at its full size)."""
        return sum(t.element_size() * t.nelement() for t in self.data.values())

    def add(self, rows: dict[str, Tensor]) -> None:
        n = next(iter(rows.values())).shape[0]
        idx = (torch.arange(n) + self.pos) % self.capacity
        for k, t in self.data.items():
            t[idx] = rows[k].to(t.dtype)
        self.pos = (self.pos + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def sample(self, n: int, generator: torch.Generator) -> dict[str, Tensor]:
        idx = torch.randint(0, self.size, (n,), generator=generator)
        return {k: t[idx] for k, t in self.data.items()}

    def state_dict(self) -> dict:
        return {"pos": self.pos, "size": self.size, "data": {k: t[: self.size].clone() for k, t in self.data.items()}}

    def load_state_dict(self, d: dict) -> None:
        self.pos, self.size = d["pos"], d["size"]
        for k, t in self.data.items():
            t[: self.size] = d["data"][k]
