"""What a trained co-design policy is compared with: the same network untrained, and
random valid designs flown by that untrained controller.

Both are evaluated on the final evaluation's seeded slews (``spec.evaluation``), so
their figures line up with ``evaluation.json`` of a finished run of the same spec.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from modsat_core.agent.policy import design_with
from modsat_core.agent.policy_file import new_actor
from modsat_core.codesign.mdp import effective_invalid_penalty
from modsat_core.evaluation.run_files import REPORT_TOLERANCES_DEG, evaluate_design
from modsat_core.grid import ACTUATOR, EMPTY, is_valid, random_design
from modsat_core.spec.jobspec import JobSpec

MAX_DRAWS = 10_000


def untrained_actor(spec: JobSpec) -> torch.nn.Module:
    """The actor a run of ``spec`` starts from (same seed, same initialisation)."""
    torch.manual_seed(spec.seed)
    actor = new_actor(spec)
    actor.eval()
    return actor


def random_valid_designs(rng: np.random.Generator, N: int, count: int) -> list[np.ndarray]:
    """``count`` distinct valid grids, each cell's type uniform over {empty, structure, actuator}."""
    out: list[np.ndarray] = []
    seen: set[bytes] = set()
    for _ in range(MAX_DRAWS):
        g = random_design(rng, N)
        if is_valid(g) and g.tobytes() not in seen:
            seen.add(g.tobytes())
            out.append(g)
            if len(out) == count:
                return out
    raise RuntimeError(f"only {len(out)} distinct valid {N}^3 designs in {MAX_DRAWS} draws")


def _flown(actor: torch.nn.Module, grid: np.ndarray, spec: JobSpec, episodes: int) -> dict:
    tols = tuple(sorted({*REPORT_TOLERANCES_DEG, spec.mission.tolerance_deg}))
    row: dict[str, Any] = {
        "modules": int((grid != EMPTY).sum()),
        "actuators": int((grid == ACTUATOR).sum()),
        "valid": bool(is_valid(grid)),
    }
    mc = evaluate_design(actor, grid, spec, episodes=episodes, seed=spec.evaluation.seed, dtype=torch.float64)
    if mc is None:
        row.update({"mean_return": effective_invalid_penalty(spec.design, spec.mission), "success_rate": 0.0})
    else:
        s = mc.summary(tols)
        row.update({k: s[k] for k in ("mean_return", "success_rate", "safety_violations", "median_final_error_deg")})
    return row


def untrained_baselines(spec: JobSpec, *, designs: int = 8, episodes: int | None = None, seed: int = 0) -> dict:
    """The untrained policy (its own design) and ``designs`` random valid designs flown by it."""
    n = episodes or spec.evaluation.episodes
    actor = untrained_actor(spec)
    own = _flown(actor, design_with(actor, spec.design, spec.mission), spec, n)
    rng = np.random.default_rng([seed, 17])
    rand = [_flown(actor, g, spec, n) for g in random_valid_designs(rng, spec.design.grid_size, designs)]
    returns = [r["mean_return"] for r in rand]
    return {
        "episodes": n,
        "untrained_policy": own,
        "random_designs": {
            "designs": rand,
            "mean_return": float(np.mean(returns)),
            "best_mean_return": float(np.max(returns)),
            "best_success_rate": float(max(r["success_rate"] for r in rand)),
        },
    }
