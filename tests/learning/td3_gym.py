"""The project's TD3 update on a standard gymnasium task (a check on code no one here wrote).

Reads like CleanRL's ``td3_continuous_action.py`` but uses :class:`modsat_core.agent.td3.TD3`,
the same update the co-design trainer uses.
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np
import torch

from modsat_core.agent.flat_networks import MLPActor, MLPCritic
from modsat_core.agent.td3 import TD3, ReplayBuffer, TD3Config

#: The TD3 settings of the gym check (frozen: a safe default argument).
GYM_TD3 = TD3Config(actor_lr=1e-3, critic_lr=1e-3)


def evaluate_gym(env_id: str, actor: torch.nn.Module, scale: np.ndarray, episodes: int, seed: int) -> float:
    """Mean undiscounted return of the deterministic policy over seeded episodes."""
    env = gym.make(env_id)
    returns = []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i)
        done, ret = False, 0.0
        while not done:
            with torch.no_grad():
                a = actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            obs, r, term, trunc, _ = env.step(a * scale)
            ret += float(r)
            done = term or trunc
        returns.append(ret)
    env.close()
    return float(np.mean(returns))


def train_gym(
    env_id: str = "Pendulum-v1",
    *,
    seed: int = 0,
    total_steps: int = 20_000,
    learning_starts: int = 1_000,
    hidden: tuple[int, ...] = (256, 256),
    batch_size: int = 256,
    exploration_noise: float = 0.1,
    eval_every: int = 2_000,
    eval_episodes: int = 10,
    target_return: float | None = None,
    cfg: TD3Config = GYM_TD3,
    on_eval: Callable[[int, float], None] | None = None,
) -> list[tuple[int, float]]:
    """Train on a Box-action gymnasium env; returns the curve [(env_steps, mean eval return)].

    Stops early once an evaluation reaches ``target_return`` (if given).
    """
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(seed)
    env = gym.make(env_id)
    obs_space, act_space = env.observation_space, env.action_space
    assert obs_space.shape is not None and isinstance(act_space, gym.spaces.Box)  # flat observations, Box actions
    obs_dim = obs_space.shape[0]
    act_dim = act_space.shape[0]
    scale = act_space.high.astype(np.float32)
    agent = TD3(MLPActor(obs_dim, act_dim, list(hidden)), MLPCritic(obs_dim, act_dim, list(hidden)), cfg)
    buf = ReplayBuffer(
        {
            "obs": ((obs_dim,), torch.float32),
            "act": ((act_dim,), torch.float32),
            "rew": ((), torch.float32),
            "next_obs": ((obs_dim,), torch.float32),
            "term": ((), torch.bool),
        },
        capacity=total_steps,
    )
    obs, _ = env.reset(seed=seed)
    curve = []
    for step in range(1, total_steps + 1):
        if step <= learning_starts:
            a = rng.uniform(-1.0, 1.0, size=act_dim).astype(np.float32)
        else:
            with torch.no_grad():
                a = agent.actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            a = np.clip(a + rng.normal(0.0, exploration_noise, size=act_dim), -1.0, 1.0).astype(np.float32)
        next_obs, r, term, trunc, _ = env.step(a * scale)
        buf.add(
            {
                "obs": torch.as_tensor(obs)[None],
                "act": torch.as_tensor(a)[None],
                "rew": torch.tensor([r], dtype=torch.float32),
                "next_obs": torch.as_tensor(next_obs)[None],
                "term": torch.tensor([term]),
            }
        )
        obs = next_obs
        if term or trunc:
            obs, _ = env.reset()
        if step > learning_starts:
            b = buf.sample(batch_size, gen)
            agent.update(b["obs"], b["act"], b["rew"], b["next_obs"], b["term"], gen)
        if step % eval_every == 0:
            ret = evaluate_gym(env_id, agent.actor, scale, eval_episodes, seed=10_000 + seed * 100)
            curve.append((step, ret))
            if on_eval:
                on_eval(step, ret)
            if target_return is not None and ret >= target_return:
                break
    env.close()
    return curve
