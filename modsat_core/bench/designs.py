"""``modsat bench designs``: one controller for every design, flown on designs it never saw.

A `diffsim-control` run with a design pool (``diffsim.design_pool`` random valid designs besides
the run's own, the full cube) learns a design-conditioned controller on the `cpu-3x3x3` mission
(or the 5x5x5 one). It is then flown, beside PD, on ``designs`` held-out random valid designs
(drawn from a stream of their own, none of them in the training pool), ``slews`` slews each, in
float64 on the mission's own physics. One torch thread. The output is a JSON object: the run's
training time, and per controller the success over all slews, the share of designs on which every
slew landed, the median settling time and the safety violations.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import torch

from modsat_core.agent.policy import controller_for
from modsat_core.agent.policy_file import load_policy
from modsat_core.bench.codesign import design_counts
from modsat_core.bench.learners import _cpu_model, timed_train
from modsat_core.evaluation.monte_carlo import monte_carlo
from modsat_core.grid import random_valid_design
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design
from modsat_core.spec.jobspec import DesignSpace, Evaluation, JobSpec, Mission, ModuleCatalog, parse_spec
from modsat_core.spec.presets import get_preset

#: Episodes flown in one batch (memory: a 5x5x5 design pool's slews carry up to 125 wheel units).
CHUNK = 800


def designs_spec(seed: int, updates: int, pool: int, grid_size: int = 3) -> JobSpec:
    """The run: `cpu-3x3x3` (or `paper-5x5x5`'s mission and modules for 5) with `diffsim-control`
    on the full cube, a pool of ``pool`` designs, ``updates`` updates, one curve point at the end."""
    d = get_preset("cpu-3x3x3" if grid_size == 3 else "paper-5x5x5").model_dump(mode="json")
    d.update(algorithm="diffsim-control", seed=seed, name="bench-designs")
    d["design"]["fixed_design"] = reference_design(grid_size).tolist()
    d["diffsim"]["design_pool"] = pool
    steps = updates * d["diffsim"]["batch_size"] * d["diffsim"]["window_steps"]
    d["training"].update(
        total_env_steps=steps, eval_every_steps=steps, eval_episodes=8, select_top_k=1, checkpoint_every_steps=10**9
    )
    return parse_spec(d)


def held_out_designs(design_space: DesignSpace, seed: int, n: int, exclude: list[np.ndarray]) -> list[np.ndarray]:
    """``n`` distinct random valid designs of ``design_space``, none in ``exclude``; ``seed``: the run's."""
    rng = np.random.default_rng([seed, 3])
    seen = {np.asarray(g, dtype=np.int64).tobytes() for g in exclude}
    out: list[np.ndarray] = []
    while len(out) < n:
        g = random_valid_design(rng, design_space.grid_size)
        if g.tobytes() not in seen:
            seen.add(g.tobytes())
            out.append(g)
    return out


def fly_designs(
    controller, grids: list[np.ndarray], slews: int, mission: Mission, modules: ModuleCatalog, evaluation: Evaluation
) -> dict[str, Any]:
    """``controller`` (a function of the sim, or a class as PDController) on ``slews`` evaluation
    slews of each design; a summary over all of them."""
    designs = [Design.from_grid(g, modules) for g in grids for _ in range(slews)]
    episodes: list[dict] = []
    for start in range(0, len(designs), CHUNK):
        part = designs[start : start + CHUNK]
        mc = monte_carlo(part, controller, mission, modules, episodes=len(part), seed=evaluation.seed)
        episodes += mc.episodes
    ok = np.array([bool(e["success"]) for e in episodes]).reshape(len(grids), slews)
    bad = np.array([bool(e["safety_violation"]) for e in episodes]).reshape(len(grids), slews)
    settle = [e["settling_time_s"] for e in episodes if e["success"]]
    missed = [i for i in range(len(grids)) if not ok[i].all()]
    return {
        "slews": len(episodes),
        "success_rate": float(ok.mean()),
        "designs_all_landed": float(ok.all(axis=1).mean()),
        "worst_design_success": float(ok.mean(axis=1).min()),
        "median_settling_time_s": float(np.median(settle)) if settle else None,
        "safety_violations": int(bad.sum()),
        # the designs that did not land every slew, named (the first MAX_NAMED of them)
        "designs_missed": [
            {
                "index": i,
                "success_rate": float(ok[i].mean()),
                "safety_violations": int(bad[i].sum()),
                **design_figures(grids[i], modules),
            }
            for i in missed[:MAX_NAMED]
        ],
    }


#: How many of the designs that missed a slew a report names.
MAX_NAMED = 10


def design_figures(grid: np.ndarray, modules: ModuleCatalog) -> dict[str, Any]:
    """What sets how a design flies: its grid, modules, wheel units, principal moments and the
    torque-to-inertia ratio of its weakest principal axis (1/s^2)."""
    d = Design.from_grid(grid, modules)
    moments = np.linalg.eigvalsh(d.I_B)
    return {
        "grid": np.asarray(grid).tolist(),
        **design_counts(grid),
        "principal_moments_kgm2": [round(float(m), 6) for m in moments],
        "weakest_axis_accel_rad_s2": round(d.n_actuators * modules.torque_scale_Nm / float(moments[-1]), 6),
    }


def bench_designs(seed: int, updates: int, pool: int, designs: int, slews: int, grid_size: int = 3) -> dict:
    """Train (see :func:`designs_spec`) and fly the held-out designs (module docstring)."""
    torch.set_num_threads(1)
    spec = designs_spec(seed, updates, pool, grid_size)
    files, train_s, _wall = timed_train(spec)
    actor, grid, spec = load_policy(files["policy.pt"])
    assert grid is not None  # a diffsim-control run flies its fixed design
    from modsat_core.training.diffsim import DiffsimRun

    pool_grids = [d.grid for d in DiffsimRun(spec).pool]  # the designs training flew (re-drawn, same seed)
    grids = held_out_designs(spec.design, spec.seed, designs, pool_grids)
    own = json.loads(files["evaluation.json"])
    return {
        "seed": seed,
        "grid_size": grid_size,
        "updates": updates,
        "design_pool": pool,
        "train_s": round(train_s, 1),
        "held_out_designs": designs,
        "slews_per_design": slews,
        "diffsim": fly_designs(
            controller_for(actor, grid, spec), grids, slews, spec.mission, spec.modules, spec.evaluation
        ),
        "pd": fly_designs(PDController, grids, slews, spec.mission, spec.modules, spec.evaluation),
        "run_design": {
            "success_rate_at_0.25_deg": own["policy"]["summary"].get("success_rate_at_0.25_deg"),
            "median_settling_time_s": own["policy"]["summary"]["median_settling_time_s"],
            "pd_median_settling_time_s": own["pd_baseline"]["summary"]["median_settling_time_s"],
        },
        "cpu": _cpu_model(),
        "torch": torch.__version__,
    }
