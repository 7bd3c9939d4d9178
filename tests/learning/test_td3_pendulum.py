"""The project's TD3 update on a task no one here wrote: gymnasium's Pendulum-v1.

The RL Zoo's TD3 reaches -152 +/- 90 there; the issue asks for a mean evaluation return
of at least -200 within 20k env steps for each of 3 seeds. Training stops at the first
evaluation (every 1k steps, 10 episodes) that reaches -200.
"""

from __future__ import annotations

import pytest

from modsat_core.agent.td3 import TD3Config
from tests.learning.td3_gym import train_gym

pytestmark = pytest.mark.slow  # trains TD3 on Pendulum-v1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_td3_solves_pendulum(seed):
    curve = train_gym(
        "Pendulum-v1",
        seed=seed,
        total_steps=20_000,
        learning_starts=1_000,
        hidden=(64, 64),
        batch_size=128,
        eval_every=1_000,
        eval_episodes=10,
        target_return=-200.0,
        cfg=TD3Config(actor_lr=1e-3, critic_lr=1e-3),
    )
    steps, best = curve[-1][0], max(r for _, r in curve)
    print(f"seed {seed}: best evaluation return {best:.1f} at {steps} env steps")
    assert best >= -200.0, curve
