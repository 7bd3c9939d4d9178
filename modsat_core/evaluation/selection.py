"""The snapshot a TD3 run keeps for its final evaluation.

Every learning-curve evaluation offers its policy; the run keeps the best by the curve's
rank (success first, then return). The curve's few slews (``training.eval_episodes``) pick
well between a policy that holds and one that does not, but not between two that land all
of them: a hold learned on 32 slews can still cross the rate limit on the longest of 100.
With ``training.select_top_k`` > 1 the run keeps the curve's k best and, once training ends,
flies each on a validation set of its own (as many slews as the final evaluation, from a
seed apart from the curve's and the final evaluation's) and keeps the best there. The
final evaluation then measures the kept policy on slews it was not chosen on.
"""

from __future__ import annotations

import numpy as np
import torch

from modsat_core.agent.policy_file import actor_from_state
from modsat_core.evaluation.run_files import evaluate_design
from modsat_core.spec.jobspec import Evaluation, JobSpec


def rank(point: dict) -> tuple[float, float]:
    """Snapshots are compared by success rate first, then by return (a policy that lands
    more slews beats one that collects more shaping reward without landing them)."""
    return point.get("success_rate", 0.0), point["mean_return"]


def validation_seed(evaluation: Evaluation) -> int:
    """Seed of the validation slews: apart from the curve's and the final evaluation's."""
    return (evaluation.seed + 104_729) % (2**31)


def keep(kept: list[dict], point: dict, actor: torch.nn.Module, grid: np.ndarray, k: int) -> list[dict]:
    """``kept`` (best first, at most k) after the curve's ``point`` of ``actor`` flying ``grid``:
    its snapshot takes its place if it ranks among the k best; an earlier snapshot stays ahead
    of a later one of the same rank."""
    r = rank(point)
    if len(kept) >= k and r <= rank(kept[-1]):
        return kept
    snapshot = {
        "mean_return": point["mean_return"],
        "success_rate": point["success_rate"],
        "env_steps": point["env_steps"],
        "grid": grid,
        "actor": {n: v.detach().cpu().clone() for n, v in actor.state_dict().items()},
    }
    at = next((i for i, s in enumerate(kept) if rank(s) < r), len(kept))
    return [*kept[:at], snapshot, *kept[at:]][:k]


def validate(kept: list[dict], spec: JobSpec) -> tuple[dict, list[dict]]:
    """The snapshot of ``kept`` that does best on the validation slews (by :func:`rank`;
    the curve's order breaks ties), and what each scored there. One snapshot: itself,
    unflown."""
    if len(kept) == 1:
        return kept[0], []
    scores = []
    for s in kept:
        mc = evaluate_design(
            actor_from_state(spec, s["actor"]),
            np.asarray(s["grid"], dtype=np.int64),
            spec,
            episodes=spec.evaluation.episodes,
            seed=validation_seed(spec.evaluation),
        )
        summary = {"success_rate": 0.0, "mean_return": s["mean_return"]} if mc is None else mc.summary()
        scores.append(
            {
                "env_steps": s["env_steps"],
                "curve_success_rate": s["success_rate"],
                "curve_mean_return": s["mean_return"],
                "success_rate": float(summary["success_rate"]),
                "mean_return": float(summary["mean_return"]),
                "safety_violations": int(summary.get("safety_violations", 0)),
            }
        )
    best = max(range(len(kept)), key=lambda i: (rank(scores[i]), -i))
    return kept[best], scores
