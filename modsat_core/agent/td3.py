"""TD3 (Fujimoto et al. 2018): the update and the replay buffer, as plain pieces.

The networks live in :mod:`modsat_core.agent.networks`. The update is one function over any
actor/critic pair that follows a small protocol:
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
    action_l2: float = 0.0
    design_bc: float = 0.0

    @classmethod
    def from_training(cls, t) -> TD3Config:
        """The update's settings of a spec's ``training`` section (the one place they are read)."""
        return cls(
            gamma=t.gamma,
            tau=t.tau,
            policy_noise=t.policy_noise,
            noise_clip=t.noise_clip,
            policy_delay=t.policy_delay,
            actor_lr=t.actor_lr,
            critic_lr=t.critic_lr,
            action_l2=t.action_l2,
            design_bc=t.design_bc,
        )


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

    def update(
        self,
        obs,
        action: Tensor,
        reward: Tensor,
        next_obs,
        terminal: Tensor,
        generator: torch.Generator,
        actor_rows: Tensor | None = None,
    ) -> dict[str, float]:
        """One TD3 step on a batch; the actor and targets move every ``policy_delay`` calls.

        ``actor_rows``: (B,) bool, the rows whose actions the actor step improves (default
        all); the critic learns from every row."""
        cfg = self.cfg
        with torch.no_grad():
            next_a = self.actor_target(next_obs)
            noise = torch.randn(next_a.shape, generator=generator, device=next_a.device) * cfg.policy_noise
            # finish: a static method of each actor class; typed nn.Module, mypy sees __getattr__'s Tensor | Module.
            next_a = self.actor_target.finish(  # type: ignore[operator]
                next_obs, next_a + noise.clamp(-cfg.noise_clip, cfg.noise_clip)
            )
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
            # The critic is held fixed here: no gradients for its weights (only through it
            # to the action), which also skips the backward pass of its action-free parts.
            for p in self.critic.parameters():
                p.requires_grad_(False)
            try:
                a_pi = self.actor(obs)
                q_pi = self.critic(obs, a_pi)[0]
                per_row = -q_pi
                if cfg.design_bc:  # imitation: a static method of each actor class, as effort
                    gap, rows = self.actor.imitation(obs, a_pi, action)  # type: ignore[operator]
                    w = rows.to(q_pi.dtype)  # TD3+BC's scale: the mean |Q| of the rows imitated
                    scale = (q_pi.detach().abs() * w).sum() / w.sum().clamp(min=1.0)
                    per_row = per_row + cfg.design_bc * scale * gap
                if cfg.action_l2:  # effort: a static method of each actor class, as finish
                    per_row = per_row + cfg.action_l2 * self.actor.effort(obs, a_pi)  # type: ignore[operator]
                if actor_rows is None:
                    actor_loss = per_row.mean()
                else:  # an empty selection is a zero loss: no gradient, no step of any weight
                    actor_loss = (per_row * actor_rows.to(per_row.dtype)).sum() / actor_rows.sum().clamp(min=1)
                self.actor_opt.zero_grad(set_to_none=True)
                actor_loss.backward()
            finally:
                for p in self.critic.parameters():
                    p.requires_grad_(True)
            self.actor_opt.step()
            soft_update(self.actor_target, self.actor, cfg.tau)
            soft_update(self.critic_target, self.critic, cfg.tau)
            info["actor_loss"] = actor_loss.item()
        return info

    def state_dict(self) -> dict:
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "actor_target": self.actor_target.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
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
            if k in d["data"]:
                t[: self.size] = d["data"][k]
            else:  # a field this checkpoint's buffer predates: zeros
                t[: self.size] = 0
