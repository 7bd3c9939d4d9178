"""``modsat bench control``: is a spec's mission learnable by TD3 at all, and at what cost?

A diagnostic beside the co-design runs. It trains a plain MLP actor-critic pair with the
project's TD3 update (the one `td3_gym` checks on Pendulum-v1) to fly one fixed design --
`design.fixed_design`, else the full cube with the centre actuator -- on the spec's
mission, from the satellite's flat state: the same 23 numbers the co-design network's
control part sees on an actuator cell (error quaternion, its rate, body rate, the fine
error channel, the wheel momentum). No design phase, no per-cell network: one row per
state instead of N^3, so an update costs a fraction of a co-design update and the width of
the network can be varied cheaply.

Uses the spec's mission, modules and training settings (envs, budget, network sizes,
learning rates, batch, update ratio, noise). Every
``eval_every`` env steps the deterministic actor flies the spec's final evaluation slews
(`evaluation.episodes`, `evaluation.seed`), the same Monte-Carlo the co-design runs report.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from modsat_core.agent.flat_networks import MLPActor, MLPCritic
from modsat_core.agent.td3 import TD3, ReplayBuffer, TD3Config
from modsat_core.codesign.features import control_globals
from modsat_core.evaluation.monte_carlo import monte_carlo
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import JobSpec

_CURVE_KEYS = (
    "mean_return",
    "success_rate",
    "success_rate_at_0.25_deg",
    "success_rate_at_1_deg",
    "safety_violations",
    "median_final_error_deg",
    "median_final_rate_rad_s",
    "median_slew_time_ratio",
    "median_settling_time_s",
    "max_peak_rate_rad_s",
)


def flat_state(sim: SlewSim) -> Tensor:
    """(B, 20 + 3K) float32: what the co-design control features hold, for the whole satellite."""
    h = (sim.state.h_B / sim.h_scale_Nms).reshape(sim.B, -1)
    glob = control_globals(sim.error_quaternion(), sim.state.omega_B, sim.mission.rate_limit_rad_s)
    return torch.cat((glob, h), dim=-1).float()


class _Controller:
    def __init__(self, actor: torch.nn.Module, K: int):
        self.actor, self.K = actor, K

    def __call__(self, sim: SlewSim) -> Tensor:
        return self.actor(flat_state(sim)).reshape(sim.B, self.K, 3).to(sim.dtype)


def bench_control(
    spec: JobSpec,
    *,
    eval_every: int = 5_000,
    eval_target: bool = False,
    log: Callable[[str], None] | None = None,
    max_wall_s: float | None = None,
) -> dict:
    """Train and evaluate; returns the curve and the cost (JSON-ready). ``eval_target``: each
    evaluation also flies the target actor (TD3's Polyak average of the actor), as ``"target"``.
    ``max_wall_s``: stop once training (evaluations not counted) has taken this long."""
    m, t = spec.mission, spec.training
    grid = (
        np.asarray(spec.design.fixed_design)
        if spec.design.fixed_design is not None
        else reference_design(spec.design.grid_size)
    )
    design = Design.from_grid(grid, spec.modules)
    K, B = design.n_actuators, t.num_envs
    hidden = list(t.hidden_sizes)
    torch.manual_seed(spec.seed)
    gen = torch.Generator().manual_seed(spec.seed)
    rngs = [np.random.default_rng([spec.seed, 1, i]) for i in range(B)]
    sim = SlewSim.from_designs([design] * B, m, spec.modules, dtype=torch.float32)
    sim.reset(list(range(B)), [draw_episode(r, m) for r in rngs])
    obs_dim, act_dim = flat_state(sim).shape[1], 3 * K
    critic = MLPCritic(obs_dim, act_dim, hidden)
    actor = MLPActor(obs_dim, act_dim, hidden, mirror_at=0 if t.odd_control else None)
    agent = TD3(actor, critic, TD3Config.from_training(t))
    buf = ReplayBuffer(
        {
            "o": ((obs_dim,), torch.float32),
            "a": ((act_dim,), torch.float32),
            "r": ((), torch.float32),
            "o2": ((obs_dim,), torch.float32),
            "d": ((), torch.bool),
        },
        capacity=min(t.buffer_size, max(t.total_env_steps, t.batch_size)),
    )
    curve: list[dict] = []
    steps, credit, next_eval, t0 = 0, 0.0, eval_every, time.monotonic()

    def fly(actor: torch.nn.Module) -> dict:
        mc = monte_carlo(
            design,
            _Controller(actor, K),
            m,
            spec.modules,
            episodes=spec.evaluation.episodes,
            seed=spec.evaluation.seed,
            dtype=torch.float64,
        )
        s = mc.summary((0.25, 1.0))
        return {k: s[k] for k in _CURVE_KEYS}

    def say(who: str, p: dict) -> None:
        if log is not None:
            log(
                f"  {steps:,} steps, {agent.updates:,} updates, {p['wall_s']:,.0f} s{who}: return "
                f"{p['mean_return']:.1f}, success {100 * p['success_rate']:.0f} %, median error "
                f"{p['median_final_error_deg']:.2f} deg, median final rate "
                f"{p['median_final_rate_rad_s']:.4f} rad/s"
            )

    eval_s = 0.0

    def evaluate() -> dict:
        nonlocal eval_s
        e0 = time.monotonic()
        point: dict = {"env_steps": steps, "updates": agent.updates, "wall_s": round(e0 - t0, 1)}
        point.update(fly(agent.actor))
        say("", point)
        if eval_target:
            target = fly(agent.actor_target)
            point["target"] = target
            say(" (target actor)", {**point, **target})
        curve.append(point)
        eval_s += time.monotonic() - e0
        return point

    def out_of_time() -> bool:
        return max_wall_s is not None and time.monotonic() - t0 - eval_s >= max_wall_s

    while steps + B <= t.total_env_steps and not out_of_time():
        o = flat_state(sim)
        if steps < t.learning_starts:
            a = torch.rand((B, act_dim), generator=gen) * 2.0 - 1.0
        else:
            with torch.no_grad():
                a = agent.actor(o)
            a = (a + torch.randn(a.shape, generator=gen) * t.noise_at(steps)).clamp(-1.0, 1.0)
        out = sim.step(a.reshape(B, K, 3))
        buf.add({"o": o, "a": a, "r": out.reward.float(), "o2": flat_state(sim), "d": out.terminated})
        ended = (out.terminated | out.truncated).nonzero().flatten().tolist()
        if ended:
            sim.reset(ended, [draw_episode(rngs[i], m) for i in ended])
        steps += B
        if steps >= t.learning_starts and buf.size >= t.batch_size:
            credit += B / t.train_frequency
            while credit >= 1.0:
                credit -= 1.0
                b = buf.sample(t.batch_size, gen)
                agent.update(b["o"], b["a"], b["r"], b["o2"], b["d"], gen)
        if steps >= next_eval:
            evaluate()
            next_eval += eval_every
    train_s = time.monotonic() - t0 - eval_s
    if not curve or curve[-1]["env_steps"] != steps:
        evaluate()
    pd = monte_carlo(
        design, PDController, m, spec.modules, episodes=spec.evaluation.episodes, seed=spec.evaluation.seed
    )
    best = max(curve, key=lambda p: p["mean_return"])
    return {
        "benchmark": "control",
        "design": grid.tolist(),
        "hidden_sizes": hidden,
        "seed": spec.seed,
        "wall_s": round(time.monotonic() - t0, 1),
        "train_s": round(train_s, 1),
        "env_steps": steps,
        "updates": agent.updates,
        "threads": torch.get_num_threads(),
        "curve": curve,
        "best": best,
        "pd_baseline": {
            k: v
            for k, v in pd.summary((0.25, 1.0)).items()
            if k
            in (
                "mean_return",
                "success_rate",
                "success_rate_at_0.25_deg",
                "success_rate_at_1_deg",
                "median_slew_time_ratio",
            )
        },
    }
