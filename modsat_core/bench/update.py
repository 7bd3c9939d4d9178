"""``modsat bench update``: what one TD3 update costs with each network, in one run.

One update = :meth:`TD3.update` (twin critics, and on every ``policy_delay``-th call the
actor and the Polyak targets), on a batch sampled from a replay buffer of flying states
of the full N^3 cube with the centre actuator. Three networks, same widths:

- ``flat``: the MLP pair of ``bench control`` on the satellite's flat state (no per-cell
  rows; the floor any co-design network is measured against);
- ``per-module``: the paper's network, its trunk run on every cell;
- ``set``: per-cell encoder, pooling, wide layers once per satellite.

Times are medians over timed rounds in which the networks take turns (so a load change on
the machine hits them alike), with the per-cell features rebuilt from the compact rows
outside the timed update and reported on their own (``features_ms``). Ratios are to
``flat`` on the same grid.
"""

from __future__ import annotations

import platform
import statistics
import time

import torch

from modsat_core.agent.flat_networks import MLPActor, MLPCritic
from modsat_core.agent.networks import NETWORKS, make_actor, make_critic
from modsat_core.agent.td3 import TD3, TD3Config
from modsat_core.codesign.features import N_CONTROL_GLOBAL, N_FEATURES
from modsat_core.codesign.mdp import Compact, observe_compact
from modsat_core.grid import ACTUATOR


def _compact_batch(N: int, batch: int, gen: torch.Generator) -> Compact:
    C = N**3
    grid = torch.ones(batch, C, dtype=torch.uint8)
    grid[:, C // 2] = ACTUATOR  # the centre cell
    q = torch.randn(batch, 4, generator=gen)
    return Compact(
        grid=grid,
        design_step=torch.full((batch,), 10, dtype=torch.int16),
        q_BN=q / q.norm(dim=-1, keepdim=True),
        q_TN=torch.tensor([[1.0, 0, 0, 0]]).expand(batch, 4),
        omega_B=torch.randn(batch, 3, generator=gen) * 0.1,
        h_cells=(torch.randn(batch, C, 3, generator=gen) * 0.1).to(torch.float16),
    )


def _cases(N: int, hidden: list[int], batch: int, gen: torch.Generator) -> dict:
    """Per network: (agent, obs, action, reward, next_obs, terminal)."""
    reward = torch.randn(batch, generator=gen)
    terminal = torch.zeros(batch, dtype=torch.bool)
    cfg = TD3Config(actor_lr=1e-3, critic_lr=1e-3)
    flat_dim = N_CONTROL_GLOBAL + 3  # one actuator
    out: dict[str, tuple] = {
        "flat": (
            TD3(MLPActor(flat_dim, 3, hidden), MLPCritic(flat_dim, 3, hidden), cfg),
            torch.randn(batch, flat_dim, generator=gen),
            torch.rand(batch, 3, generator=gen) * 2 - 1,
            reward,
            torch.randn(batch, flat_dim, generator=gen),
            terminal,
        )
    }
    obs = observe_compact(_compact_batch(N, batch, gen), N, 10, 0.5)
    nxt = observe_compact(_compact_batch(N, batch, gen), N, 10, 0.5)
    action = (torch.rand(batch, N**3, 3, generator=gen) * 2 - 1) * obs.act_mask.unsqueeze(-1)
    for name in NETWORKS:
        agent = TD3(make_actor(name, N_FEATURES, hidden), make_critic(name, N_FEATURES, hidden), cfg)
        out[name] = (agent, obs, action, reward, nxt, terminal)
    return out


def bench_update(
    grids: tuple[int, ...] = (3, 5),
    hidden: tuple[int, ...] = (256, 256),
    batch: int = 256,
    rounds: int = 5,
    updates_per_round: int = 2,
    threads: int | None = 1,
) -> dict:
    """Milliseconds per TD3 update for ``flat`` and each co-design network, per grid."""
    if threads is not None:
        torch.set_num_threads(threads)
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    results: dict[str, dict] = {}
    for N in grids:
        cases = _cases(N, list(hidden), batch, gen)
        times: dict[str, list[float]] = {k: [] for k in cases}
        for agent, *args in cases.values():  # warm-up: first calls allocate
            for _ in range(2):
                agent.update(*args, generator=gen)
        for _ in range(rounds):
            for name, (agent, *args) in cases.items():
                t0 = time.perf_counter()
                for _ in range(updates_per_round):
                    agent.update(*args, generator=gen)
                times[name].append((time.perf_counter() - t0) * 1e3 / updates_per_round)
        comp = _compact_batch(N, batch, gen)
        feat = []
        for _ in range(rounds):
            t0 = time.perf_counter()
            observe_compact(comp, N, 10, 0.5)
            feat.append((time.perf_counter() - t0) * 1e3)
        row = {f"{k}_ms": round(statistics.median(v), 2) for k, v in times.items()}
        for k in NETWORKS:
            row[f"{k}_ratio"] = round(row[f"{k}_ms"] / row["flat_ms"], 2)
        row["features_ms"] = round(statistics.median(feat), 2)
        row["cells"] = N**3
        results[f"{N}x{N}x{N}"] = row
    return {
        "benchmark": "update",
        "unit": "milliseconds per TD3 update (critics; actor and targets every 2nd)",
        "hidden_sizes": list(hidden),
        "batch_size": batch,
        "rounds": rounds,
        "updates_per_round": updates_per_round,
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "machine": platform.machine(),
        "results": results,
    }
