"""The CPU recipe lands the slew: success itself, asserted on a measured run.

`modsat bench control`'s flat TD3 controller flies the full cube with the centre actuator on
the `quick` mission (30-90 deg slews, 1 deg and 0.01 rad/s at the end of 120 steps) with
the CPU presets' recipe: the finer error and rate features, [256, 256], lr 1e-3, one update
per env step, exploration noise falling to zero, and the hold reward (no progress penalty
inside the cone, the settle bonus), 40k env steps, and the actor's action penalty
(`training.action_l2` 10). docs/lab/2026-12-03-action-penalty-quick-codesign.md (e53-e55): on one torch thread, seed 0
lands 0, 3, 34, 88, 88, 94, 97 and 100 % of 32 slews at 5k-40k; seeds 1 and 2 reach 91 and
94 % and end at 78 and 88 %. Without the penalty seed 0 ends at 12.5 % (its best) on one
thread: the hold chatters through the rate tolerance. The untrained controller lands none,
so 75 % over 32 slews, reached and held at the end, cannot come by chance.

Those runs were made by `bench control`'s own TD3 loop, before it trained through the co-design
trainer (TD3Run with the flat networks: the replay stores compact states and float16 actions,
and the random draws differ), so the seeded run this test replays is another draw of the same
recipe until it is measured again on the AMD machine.
"""

from __future__ import annotations

import pytest

from modsat_core.sim.gym_envs import reference_design
from modsat_core.spec.jobspec import parse_spec
from modsat_core.spec.presets import get_preset
from modsat_core.training.td3_control import bench_control

from .conftest import on_the_measured_cpu

pytestmark = [pytest.mark.slow, on_the_measured_cpu]  # trains a controller for 40k env steps (minutes)


def test_flat_controller_with_the_cpu_recipe_settles_most_slews():
    d = get_preset("quick-td3").model_dump(mode="json")
    d.update(algorithm="td3-control", seed=0)
    d["design"]["fixed_design"] = reference_design(3).tolist()
    # One update per env step and the action penalty, as in the measured run (e53), whose
    # actor was not odd (`quick` now has `odd_control`).
    d["training"].update(total_env_steps=40_000, train_frequency=1, action_l2=10.0, odd_control=False)
    spec = parse_spec(d)
    report = bench_control(spec, eval_every=5_000)
    rates = [p["success_rate"] for p in report["curve"]]
    print("success at 5k-40k:", rates, "updates", report["updates"], "wall", report["wall_s"])
    assert rates[0] == 0.0  # nothing lands at first
    assert max(rates) >= 0.75 and rates[-1] >= 0.75  # lands, and still holds at the end
    assert report["pd_baseline"]["success_rate"] == 1.0
