"""The CPU recipe learns the slew: what every measured draw of it reaches, on any CPU.

`modsat bench control`'s flat TD3 controller flies the full cube with the centre actuator on
the `quick` mission (30-90 deg slews, 1 deg and 0.01 rad/s at the end of 120 steps) with
the CPU presets' recipe: the finer error and rate features, [256, 256], lr 1e-3, one update
per env step, exploration noise falling to zero, the hold reward (no progress penalty inside
the cone, the settle bonus) and the actor's action penalty (`training.action_l2` 10), here
over 20k env steps with the curve (the 32 final-evaluation slews) every 2.5k.

A seeded run repeats only on the same kind of CPU; on another the same seed is another draw of
the recipe, so the test asserts what every measured draw reached, not one draw's figures.
docs/lab/2026-12-05-td3-tests-on-any-cpu.md, an Intel Xeon, one torch thread, seeds 0-2 of
this spec at 20k (4.7-7.7 min each on the busy 2-core machine):

| seed | success at 2.5k ... 20k (of 32) | best median final error | best return |
|---|---|---|---|
| 0 | 0, 0, 0, 3, 0, 0, 19, 66 % | 0.23 deg | 437.2 |
| 1 | 0, 0, 0, 9, 3, 3, 12, 56 % | 0.16 deg | 416.0 |
| 2 | 0, 0, 0, 0, 0, 6, 6, 6 % | 0.67 deg | 260.3 |

At the first point (2.5k env steps, 528 updates) the median final error was 64-79 deg and the
return -49 to -11. Landing is not what every draw gives in 20k (seed 2: 2 of 32; at 40k the
AMD runs e53-e55 reached 94-100 % at best, the Intel seed 0 91 %, at 10-13 min a run): the
assertion is that the controller learns to slew and point, at its best point on the curve
(a draw's curve swings: seed 0 was back at 14.5 deg at 12.5k). The thresholds leave a margin
on the worst measured seed: median final error <= 2 deg (seed 2: 0.67, 3x under it) and a
return >= 150 (seed 2: 260.3; the first points -49 to -11). An untrained or unlearned
controller stays tens of degrees off (the first points), so neither comes by chance.
"""

from __future__ import annotations

import pytest

from modsat_core.bench.control import bench_control
from modsat_core.sim.gym_envs import reference_design
from modsat_core.spec.jobspec import parse_spec
from modsat_core.spec.presets import get_preset

pytestmark = pytest.mark.slow  # trains a controller for 20k env steps (5-8 minutes on 2 busy cores)

#: The best point on the curve must bring the median slew this close (deg); measured 0.16-0.67.
MAX_MEDIAN_ERROR_DEG = 2.0
#: ... and collect at least this return over the 32 slews; measured 260.3-437.2 (first points <= -11).
MIN_RETURN = 150.0


def test_flat_controller_with_the_cpu_recipe_learns_to_point():
    d = get_preset("quick-td3").model_dump(mode="json")
    d.update(algorithm="td3-control", seed=0)
    d["design"]["fixed_design"] = reference_design(3).tolist()
    # One update per env step and the action penalty, as in the measured runs; the actor not
    # odd (as e53, which `quick` predates in that); neither the last command nor the randomise
    # curriculum, which the flat network does not have (and which this nominal run predates).
    d["training"].update(
        total_env_steps=20_000,
        train_frequency=1,
        action_l2=10.0,
        odd_control=False,
        observe_last_command=False,
        randomise_after_success=None,
    )
    spec = parse_spec(d)
    report = bench_control(spec, eval_every=2_500)
    curve = report["curve"]
    errors = [round(p["median_final_error_deg"], 2) for p in curve]
    returns = [round(p["mean_return"], 1) for p in curve]
    rates = [p["success_rate"] for p in curve]
    print("at 2.5k-20k: success", rates, "median error deg", errors, "return", returns, "wall", report["wall_s"])
    assert len(curve) == 8
    assert rates[0] == 0.0 and errors[0] > 20.0  # at 2.5k nothing lands, the slews far off
    assert min(errors) <= MAX_MEDIAN_ERROR_DEG
    assert max(returns) >= MIN_RETURN
    assert report["pd_baseline"]["success_rate"] == 1.0
