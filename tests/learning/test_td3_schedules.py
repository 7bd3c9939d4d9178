"""TD3's schedules over the budget: `training.lr_final_fraction` (both learning rates) and
`training.policy_noise_final` (the target smoothing std)."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from modsat_core.training.td3_control import bench_control
from modsat_core.training.td3_trainer import TD3Run
from modsat_core.training.train import train

from .conftest import first_checkpoint, tiny_spec


def _lrs(run: TD3Run) -> tuple[float, float]:
    return run.agent.actor_opt.param_groups[0]["lr"], run.agent.critic_opt.param_groups[0]["lr"]


def test_the_scale_falls_from_one_when_learning_starts_to_the_fraction_at_the_end():
    t = tiny_spec(training__lr_final_fraction=0.1).training  # learning starts at 96 of 480 steps
    assert t.lr_scale_at(0) == 1.0 and t.lr_scale_at(96) == 1.0
    assert math.isclose(t.lr_scale_at(96 + 192), 0.55)
    assert math.isclose(t.lr_scale_at(480), 0.1) and math.isclose(t.lr_scale_at(10**6), 0.1)
    assert tiny_spec().training.lr_scale_at(480) == 1.0  # off by default: the paper's constant rates
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValidationError, match="lr_final_fraction"):
            tiny_spec(training__lr_final_fraction=bad)


def test_the_target_smoothing_falls_to_its_final_value():
    t = tiny_spec(training__policy_noise=0.2, training__policy_noise_final=0.01).training
    assert t.policy_noise_at(96) == 0.2 and math.isclose(t.policy_noise_at(96 + 192), 0.105)
    assert math.isclose(t.policy_noise_at(480), 0.01)
    assert tiny_spec().training.policy_noise_at(480) == 0.2  # off by default: the paper's constant std
    run = TD3Run(tiny_spec(training__policy_noise=0.2, training__policy_noise_final=0.01, design__repair=True))
    assert run.agent.policy_noise == 0.2
    run.run(lambda p: None, lambda ck: None, lambda: False)
    assert math.isclose(run.agent.policy_noise, 0.01)
    plain = TD3Run(tiny_spec(design__repair=True))
    plain.run(lambda p: None, lambda ck: None, lambda: False)
    assert plain.agent.policy_noise == 0.2


def test_a_run_s_updates_use_the_scheduled_rates():
    spec = tiny_spec(training__lr_final_fraction=0.1, training__actor_lr=1e-3, training__critic_lr=2e-3)
    run = TD3Run(spec)
    assert _lrs(run) == (1e-3, 2e-3)
    run.run(lambda p: None, lambda ck: None, lambda: False)
    assert run.env_steps == 480  # the last update ran at the end of the budget, at the final fraction
    a, c = _lrs(run)
    assert math.isclose(a, 1e-4) and math.isclose(c, 2e-4)


def test_resume_reproduces_the_uninterrupted_run():
    spec = tiny_spec(training__lr_final_fraction=0.2, design__repair=True)
    full = train(spec)
    assert train(spec, checkpoint=first_checkpoint(spec)).curve == full.curve


def test_bench_control_follows_the_schedule_and_can_fly_the_target_actor():
    spec = tiny_spec(training__total_env_steps=400, training__lr_final_fraction=0.1)
    report = bench_control(spec, eval_every=200, eval_target=True)
    assert [p["env_steps"] for p in report["curve"]] == [200, 400]
    for p in report["curve"]:
        assert set(p["target"]) <= set(p) and 0.0 <= p["target"]["success_rate"] <= 1.0
    # the target actor is a different network from the actor (a Polyak average), so its flights differ
    assert any(p["target"]["mean_return"] != p["mean_return"] for p in report["curve"])
    plain = bench_control(tiny_spec(training__total_env_steps=400), eval_every=200)
    assert "target" not in plain["curve"][0]
    assert plain["curve"] != [{k: v for k, v in p.items() if k != "target"} for p in report["curve"]]
