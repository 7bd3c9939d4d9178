"""The snapshot a run keeps (modsat_core/evaluation/selection.py): the curve's k best, and the best of
them on the validation slews."""

from __future__ import annotations

import json

import numpy as np
import torch

from modsat_core.agent.policy import design_with
from modsat_core.agent.policy_file import new_actor
from modsat_core.evaluation.selection import keep, rank, validate
from modsat_core.training.train import train


def _point(env_steps: int, success: float, ret: float) -> dict:
    return {"env_steps": env_steps, "success_rate": success, "mean_return": ret}


def test_keep_holds_the_k_best_by_success_then_return_earliest_first():
    actor, grid = torch.nn.Linear(2, 2), np.zeros((2, 2, 2), dtype=np.int64)
    kept: list[dict] = []
    for p in [_point(1, 0.0, 5.0), _point(2, 0.5, 1.0), _point(3, 0.5, 1.0), _point(4, 0.5, 2.0), _point(5, 0.0, 9.0)]:
        kept = keep(kept, p, actor, grid, 3)
    assert [s["env_steps"] for s in kept] == [4, 2, 3]  # 3 ties 2 and stays behind it; 1 and 5 rank lower
    assert set(kept[0]["actor"]) == {"weight", "bias"}
    one: list[dict] = []
    for p in [_point(1, 0.5, 1.0), _point(2, 0.5, 1.0), _point(3, 0.0, 8.0)]:
        one = keep(one, p, actor, grid, 1)
    assert [s["env_steps"] for s in one] == [1]  # k = 1: the curve's first best, as before the option


def test_validate_keeps_the_best_on_the_validation_slews_not_the_curves_first(tiny):
    spec = tiny(training__select_top_k=2, evaluation={"episodes": 6, "trajectories": 1})
    snapshots = []
    for seed in (0, 1):
        torch.manual_seed(seed)
        actor = new_actor(spec)
        grid = design_with(actor, spec.design, spec.mission)
        snapshots.append(
            {
                "env_steps": seed,
                "success_rate": 0.0,
                "mean_return": 0.0,
                "grid": grid,
                "actor": {k: v.clone() for k, v in actor.state_dict().items()},
            }
        )
    _, scores = validate(snapshots, spec)
    assert [s["env_steps"] for s in scores] == [0, 1]
    assert rank(scores[0]) != rank(scores[1])  # two random policies score apart on 6 slews
    worse_first = sorted(snapshots, key=lambda s: rank(scores[s["env_steps"]]))
    chosen, again = validate(worse_first, spec)
    assert chosen is worse_first[1]
    assert [s["env_steps"] for s in again] == [s["env_steps"] for s in worse_first]
    single, none = validate(worse_first[:1], spec)
    assert single is worse_first[0] and none == []  # one snapshot: not flown again


def test_a_run_with_select_top_k_records_its_choice_in_curve_json(tiny):
    spec = tiny(training__select_top_k=2)
    result = train(spec)
    curve = json.loads(result.files["curve.json"])
    sel = curve["selection"]
    assert len(sel) == 2 and len(curve["points"]) == 3
    by_curve = sorted(curve["points"], key=lambda p: rank(p), reverse=True)
    assert {s["env_steps"] for s in sel} <= {p["env_steps"] for p in curve["points"]}
    assert sel[0]["env_steps"] == by_curve[0]["env_steps"]
    best = max(sel, key=lambda s: (rank(s), -sel.index(s)))
    assert curve["best_env_steps"] == best["env_steps"]
    plain = json.loads(train(tiny()).files["curve.json"])
    assert "selection" not in plain or plain["selection"] is None
