"""``modsat bench control``: is a spec's mission learnable by TD3 at all, and at what cost?

A diagnostic beside the co-design runs. The co-design trainer (:class:`TD3Run`, its acting,
replay and updates) trains a plain MLP actor-critic pair (:class:`FlatCellActor`) to fly one
fixed design -- `design.fixed_design`, else the full cube with the centre actuator -- on the
spec's mission, from the satellite's flat state: the control features of the co-design network
(error quaternion, its rate, body rate, the fine error channel) and every actuator's wheel
momentum. No design phase, no per-cell network: the width of the network can be varied cheaply.

Uses the spec's mission, modules and training settings (envs, budget, network sizes,
learning rates, batch, update ratio, noise). Every ``eval_every`` env steps the deterministic
actor flies the spec's final evaluation slews (`evaluation.episodes`, `evaluation.seed`), the
same Monte-Carlo the co-design runs report, in place of the run's learning curve.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch

from modsat_core.agent.policy import controller_for
from modsat_core.evaluation.monte_carlo import monte_carlo
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design
from modsat_core.spec.jobspec import JobSpec
from modsat_core.training.td3_trainer import TD3Run

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
    hidden = list(t.hidden_sizes)
    run = TD3Run(spec, fixed_grid=grid, flat=True)
    t0 = time.monotonic()
    agent, B = run.agent, run.env.B
    curve: list[dict] = []
    next_eval = eval_every

    def fly(actor: torch.nn.Module) -> dict:
        mc = monte_carlo(
            design,
            controller_for(actor, grid, spec),
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
                f"  {p['env_steps']:,} steps, {p['updates']:,} updates, {p['wall_s']:,.0f} s{who}: return "
                f"{p['mean_return']:.1f}, success {100 * p['success_rate']:.0f} %, median error "
                f"{p['median_final_error_deg']:.2f} deg, median final rate "
                f"{p['median_final_rate_rad_s']:.4f} rad/s"
            )

    eval_s = 0.0

    def evaluate() -> dict:
        nonlocal eval_s
        e0 = time.monotonic()
        point: dict = {"env_steps": run.env_steps, "updates": agent.updates, "wall_s": round(e0 - t0, 1)}
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

    while run.env_steps + B <= t.total_env_steps and not out_of_time():
        run.step()
        if run.env_steps >= next_eval:
            evaluate()
            next_eval += eval_every
    train_s = time.monotonic() - t0 - eval_s
    if not curve or curve[-1]["env_steps"] != run.env_steps:
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
        "env_steps": run.env_steps,
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
