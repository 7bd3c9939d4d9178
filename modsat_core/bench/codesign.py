"""``modsat bench codesign``: what `diffsim-codesign` designs, against the initial design and random
designs flown by the same controller.

One `diffsim-codesign` run of a preset (`diffsim-3x3x3`) and seed, timed from its start to its
final evaluation. Then its controller (at the end of training) flies, on the same ``slews`` slews
(a seed of their own, not the validation slews the kept design was chosen on), in float64 on the
mission's physics: the kept design; the initial design (the full cube of structure modules with its
centre actuator, the paper's initial design, the payload included); and ``designs`` random valid
designs from the distribution the run starts from (every free cell empty, structure or actuator
with equal chance, the payload kept). PD flies the same. Each is scored by the objective (seconds,
lower is better). Then the GA on the same objective and env-step budget (:func:`ga_row`): its best
design flown by its own controller on the same slews. One torch thread. The output is a JSON
object.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import torch

from modsat_core.agent.policy_file import load_policy
from modsat_core.bench.learners import _cpu_model, timed_train
from modsat_core.grid import ACTUATOR, EMPTY
from modsat_core.sim.pd import PDController
from modsat_core.spec.jobspec import DesignSpace, JobSpec, Objective, parse_spec
from modsat_core.spec.presets import get_preset
from modsat_core.training.diffsim_codesign import fixed_cells, initial_design, satellites, score_designs


def random_designs(design_space: DesignSpace, objective: Objective, n: int, seed: int) -> list[np.ndarray]:
    """``n`` valid satellites drawn from the uniform per-cell distribution, the payload kept."""
    fixed, types = fixed_cells(design_space, objective)
    rng = np.random.default_rng([seed, 7])
    N = design_space.grid_size
    out: list[np.ndarray] = []
    while len(out) < n:
        g = satellites(rng.integers(0, 3, size=(1, N, N, N)), fixed, types)[0]
        if (g >= ACTUATOR).any():
            out.append(g)
    return out


def design_counts(grid: np.ndarray) -> dict[str, int]:
    """A design's modules and wheel units, as the bench reports name them."""
    g = np.asarray(grid)
    return {"modules": int((g != EMPTY).sum()), "wheels": int((g >= ACTUATOR).sum())}


#: The GA of the comparison: generations of 8 designs, each its own `diffsim-control` run of 16
#: updates, the objective its fitness; the same env-step budget as the co-design run.
GA_POPULATION, GA_UPDATES_PER_DESIGN = 8, 16


def ga_row(spec: JobSpec, seed: int, cmp_seed: int, slews: int) -> dict[str, Any]:
    """The GA (``ga.inner`` diffsim, ``ga.fitness`` objective) on ``spec``'s objective and budget:
    its best design flown by its own controller on the comparison slews, and its wall time."""
    from modsat_core.agent.policy import controller_for

    d = spec.model_dump(mode="json")
    step = d["diffsim"]["batch_size"] * d["diffsim"]["window_steps"]
    d.update(algorithm="ga", seed=seed, name="bench-codesign-ga")
    d["ga"].update(
        inner="diffsim",
        fitness="objective",
        population_size=GA_POPULATION,
        steps_per_design=GA_UPDATES_PER_DESIGN * step,
    )
    d["training"].update(eval_every_steps=GA_UPDATES_PER_DESIGN * step)
    files, _train_s, wall = timed_train(parse_spec(d))
    policy, grid, ga_spec = load_policy(files["policy.pt"])
    assert grid is not None
    controller = controller_for(policy.double(), grid, ga_spec)
    score = score_designs(ga_spec, controller, [grid], slews, cmp_seed, exact=True)[0]
    ev = json.loads(files["evaluation.json"])["policy"]["summary"]
    return {
        "objective_s": score,
        **design_counts(grid),
        "wall_s": round(wall, 1),
        "designs_evaluated": len(json.loads(files["curve.json"])["designs"]),
        "own_policy_success": ev.get(f"success_rate_at_{ga_spec.mission.tolerance_deg:g}_deg"),
    }


#: What the report keeps of each design update (``relaxed_objective_s`` with the relaxed gradient).
_DESIGN_RECORD = ("updates", "mean_objective_s", "best_objective_s", "relaxed_objective_s", "modules", "actuators")


def bench_codesign(
    preset: str,
    seed: int,
    designs: int,
    slews: int,
    design_gradient: str | None = None,
    ga: bool = True,
    design_batch: int | None = None,
) -> dict[str, Any]:
    """The report of the module docstring; ``design_gradient`` and ``design_batch`` override the
    preset's, and without ``ga`` the GA row is left out."""
    torch.set_num_threads(1)
    d = get_preset(preset).model_dump(mode="json")
    d["seed"] = seed
    if design_gradient is not None:
        d["diffsim"]["design_gradient"] = design_gradient
    if design_batch is not None:
        d["diffsim"]["design_batch"] = design_batch
    spec = parse_spec(d)
    files, train_s, wall = timed_train(spec)
    policy, kept, spec = load_policy(files["policy.pt"])
    assert kept is not None
    ev = json.loads(files["evaluation.json"])
    cube = initial_design(spec.design, spec.objective, spec.modules)
    rand = random_designs(spec.design, spec.objective, designs, seed)
    grids = [kept, cube, *rand]
    cmp_seed = spec.evaluation.seed + 2
    learned = score_designs(spec, policy.double(), grids, slews, cmp_seed, exact=True)
    pd = score_designs(spec, PDController, grids, slews, cmp_seed, exact=True)
    r_learned, r_pd = np.asarray(learned[2:]), np.asarray(pd[2:])
    best = int(np.argmin(r_learned))
    curve = json.loads(files["curve.json"])
    return {
        "preset": preset,
        "seed": seed,
        "design_gradient": spec.diffsim.design_gradient,
        "design_batch": spec.diffsim.design_batch,
        "train_s": round(train_s, 1),
        "wall_s": round(wall, 1),
        "slews": slews,
        "objective_s": {
            "kept": {"diffsim": learned[0], "pd": pd[0], **design_counts(kept)},
            "initial_cube": {"diffsim": learned[1], "pd": pd[1], **design_counts(cube)},
            "random": {
                "designs": designs,
                "diffsim_best": float(r_learned.min()),
                "diffsim_median": float(np.median(r_learned)),
                "diffsim_worst": float(r_learned.max()),
                "pd_best": float(r_pd.min()),
                "pd_median": float(np.median(r_pd)),
                "pd_worst": float(r_pd.max()),
                "best_by_diffsim": design_counts(rand[best]),
            },
        },
        "ga": ga_row(spec, seed, cmp_seed, slews) if ga else None,
        "kept_design": kept.tolist(),
        "kept_changed": not np.array_equal(kept, cube),
        "own_policy_success": ev["policy"]["summary"].get(f"success_rate_at_{spec.mission.tolerance_deg:g}_deg"),
        "own_policy_violations": ev["policy"]["summary"]["safety_violations"],
        "own_policy_median_settling_s": ev["policy"]["summary"]["median_settling_time_s"],
        "pd_median_settling_s": ev["pd_baseline"]["summary"]["median_settling_time_s"],
        "design_updates": [{k: r[k] for k in _DESIGN_RECORD if k in r} for r in curve["designs"]],
        "cpu": _cpu_model(),
        "torch": torch.__version__,
    }
