"""n-step returns from the replay buffer (training.n_step): the sums, where they stop, and
the discount of the bootstrapped value, checked against a hand computation."""

from __future__ import annotations

import pytest
import torch

from modsat_core.agent.td3 import ReplayBuffer

FIELDS = {
    "reward": ((), torch.float32),
    "terminal": ((), torch.bool),
    "done": ((), torch.bool),
    "obs_t": ((), torch.int64),
    "obs_e": ((), torch.int64),
    "next_t": ((), torch.int64),
}
B, G = 2, 0.9


def _buffer(capacity: int, steps: int, done_at: dict[int, set[int]], terminal_at: dict[int, set[int]]):
    """B episodes side by side; env e's reward at step t is 10 e + t; obs/next carry t."""
    buf = ReplayBuffer(FIELDS, capacity)
    for t in range(steps):
        buf.add(
            {
                "reward": torch.tensor([10.0 * e + t for e in range(B)]),
                "terminal": torch.tensor([t in terminal_at.get(e, ()) for e in range(B)]),
                "done": torch.tensor([t in done_at.get(e, ()) or t in terminal_at.get(e, ()) for e in range(B)]),
                "obs_t": torch.tensor([t] * B),
                "obs_e": torch.arange(B),
                "next_t": torch.tensor([t + 1] * B),
            }
        )
    return buf


def _expected(e: int, t: int, n: int, steps: int, done: set[int], terminal: set[int]):
    ret, m = 0.0, 0
    for k in range(n):
        if t + k >= steps:  # not written yet
            break
        ret += G**k * (10.0 * e + t + k)
        m = k + 1
        if t + k in done or t + k in terminal:
            break
    return ret, G**m, t + m, (t + m - 1) in terminal


@pytest.mark.parametrize("capacity", [40, 14])  # 14: the ring has wrapped (7 steps of 2 kept)
def test_n_step_sums_stop_at_episode_ends_and_at_the_newest_row(capacity):
    steps, n = 20, 3
    done, terminal = {0: {5, 12}}, {1: {8}}
    buf = _buffer(capacity, steps, done, terminal)
    gen = torch.Generator().manual_seed(0)
    b, disc = buf.sample_n_step(1500, n, B, G, gen)
    seen = set()
    for i in range(len(disc)):
        t, e = int(b["obs_t"][i]), int(b["obs_e"][i])
        ret, d, nxt, term = _expected(e, t, n, steps, done.get(e, set()), terminal.get(e, set()))
        assert float(b["reward"][i]) == pytest.approx(ret, rel=1e-6), (e, t)
        assert float(disc[i]) == pytest.approx(d) and int(b["next_t"][i]) == nxt and bool(b["terminal"][i]) == term
        seen.add((e, t))
    assert len(seen) == min(capacity, steps * B), "every stored row was sampled"


def test_one_step_is_the_plain_sample():
    buf = _buffer(40, 10, {}, {})
    b, disc = buf.sample_n_step(64, 1, B, G, torch.Generator().manual_seed(1))
    assert torch.allclose(disc, torch.full_like(disc, G))
    assert torch.equal(b["next_t"], b["obs_t"] + 1)
