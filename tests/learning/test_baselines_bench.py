"""The comparison baselines (untrained policy, random valid designs) and the learning benchmarks'
plumbing, on tiny budgets: what they report, not how well anything learns."""

from __future__ import annotations

import json

import numpy as np

from modsat_core.bench.training_runs import bench_learn, bench_rl_vs_ga, ga_spec_like
from modsat_core.codesign.mdp import effective_invalid_penalty
from modsat_core.grid import is_valid
from server.cli import main
from tests.learning.baselines import random_valid_designs, untrained_baselines

from .conftest import tiny_spec


def test_random_valid_designs_are_valid_and_distinct():
    grids = random_valid_designs(np.random.default_rng(0), 3, 20)
    assert len(grids) == 20
    assert all(is_valid(g) for g in grids)
    assert len({g.tobytes() for g in grids}) == 20


def test_untrained_baselines_report_every_design():
    spec = tiny_spec()
    out = untrained_baselines(spec, designs=4)
    assert out["episodes"] == spec.evaluation.episodes
    rows = out["random_designs"]["designs"]
    assert len(rows) == 4 and all(r["valid"] for r in rows)
    low = effective_invalid_penalty(spec.design, spec.mission)
    assert all(r["mean_return"] > low for r in rows)  # valid designs are flown, not penalised
    assert out["random_designs"]["best_mean_return"] == max(r["mean_return"] for r in rows)
    own = out["untrained_policy"]
    assert own["mean_return"] == low if not own["valid"] else own["mean_return"] > low


def test_bench_learn_times_each_seed_and_compares_with_pd():
    report = bench_learn(tiny_spec(), [0, 1])
    assert [r["seed"] for r in report["runs"]] == [0, 1]
    for r in report["runs"]:
        assert r["env_steps"] <= tiny_spec().training.total_env_steps and r["wall_s"] > 0
        assert set(r["policy"]) >= {"success_rate_at_0.25_deg", "success_rate_at_1_deg", "median_slew_time_ratio"}
        assert r["pd_baseline"] is None or "success_rate_at_1_deg" in r["pd_baseline"]
    assert report["aggregate"]["mean_return"]["n"] == 2


def test_rl_vs_ga_uses_the_same_budget_and_mission():
    rl = tiny_spec()
    ga = ga_spec_like(rl, population=3, steps_per_design=64)
    assert ga.algorithm == "ga" and ga.mission == rl.mission and ga.training == rl.training
    report = bench_rl_vs_ga(rl, [0], population=3, steps_per_design=64)
    assert report["env_step_budget"] == rl.training.total_env_steps
    for key in ("rl", "ga"):
        (run,) = report["runs"][key]
        assert run["env_steps"] <= rl.training.total_env_steps
        assert report[key]["mean_return"]["n"] == 1
    assert report["runs"]["ga"][0]["designs_evaluated"] >= 3


def test_cli_bench_learn_writes_json(tmp_path, capsys):
    spec_file = tmp_path / "tiny.json"
    spec_file.write_text(tiny_spec().model_dump_json())
    assert main(["bench", "learn", str(spec_file), "--seeds", "5", "--out", str(tmp_path / "out")]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["runs"][0]["seed"] == 5
    assert json.loads((tmp_path / "out" / "bench-learn.json").read_text()) == printed
    assert (tmp_path / "out" / "td3-codesign-seed5" / "policy.pt").exists()
