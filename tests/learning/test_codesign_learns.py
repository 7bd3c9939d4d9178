"""Co-design learns the slew: `quick-td3` (TD3 co-design on the demo mission) over 10k env
steps, asserted by what every measured draw of it reaches, on any CPU.

`quick-td3` (the set network, `cpu-3x3x3`'s recipe on `quick`'s mission: 30-90 deg slews, 1 deg
and 0.01 rad/s at the end of 120 steps) lands 91 % of 100 slews on seed 0 in its 15k env steps
on AMD EPYC (q2s0, docs/lab/2026-12-04-design-trust-region-quick-5x5x5.md), but seeds 1 and 2
land 61 % and 0 %, and on another CPU the same seed is another draw (an Intel Xeon: 4 of 32 on
seed 0). Landing is not what the recipe gives every draw, and 15k env steps take 10-13 min on 2
cores. The test trains 10k env steps (the exploration noise falling to zero over them; the
design is held throughout, as `design_learning_starts` is 10k) and asserts that the kept
policy (the curve's best) learned to slew: it flies its slews much nearer and collects a far
higher return than the same network untrained and than 8 random valid designs flown by it
(`tests.learning.baselines.untrained_baselines`), on the final evaluation's 32 slews.

Measured (docs/lab/2026-12-05-td3-tests-on-any-cpu.md, an Intel Xeon, one torch thread, seeds
0-2 of this spec, 6.4-7.5 min each on the busy 2-core machine; every design the full cube):

| seed | kept policy: return, median final error, success | untrained: return, error | random designs: best return |
|---|---|---|---|
| 0 | 68.7, 5.60 deg, 0 % | -146.3, 84.4 deg | -164.7 |
| 1 | 187.2, 0.85 deg, 3 % | -136.1, 113.9 deg | -165.7 |
| 2 | 398.5, 0.08 deg, 56 % | -63.2, 88.1 deg | -149.9 |

The thresholds leave a margin on the worst measured seed (seed 0): median final error <= 15 deg
(5.60, 2.7x under it) and a return >= 0 (68.7); the untrained controller and the random
designs land none and stay 84-114 deg off with returns of -63 to -166, so neither comes by
chance. PD flies the designed satellite to 100 %.
"""

from __future__ import annotations

import pytest

from modsat_core.spec.jobspec import parse_spec
from modsat_core.spec.presets import get_preset
from modsat_core.training.train import train
from tests.learning.baselines import untrained_baselines

pytestmark = pytest.mark.slow  # trains co-design for 10k env steps (6-8 minutes on 2 busy cores)

#: The kept policy's median final error over the 32 slews (deg); measured 0.08-5.60, untrained 84-114.
MAX_MEDIAN_ERROR_DEG = 15.0
#: ... and its mean return; measured 68.7-398.5, untrained -146 to -63, random designs <= -149.9.
MIN_RETURN = 0.0


def test_codesign_on_quick_learns_the_slew():
    d = get_preset("quick-td3").model_dump(mode="json")
    assert d["seed"] == 0
    d["training"]["total_env_steps"] = 10_000
    spec = parse_spec(d)
    res = train(spec)
    trained = res.summary["policy"]
    base = untrained_baselines(spec, designs=8)
    own, rand = base["untrained_policy"], base["random_designs"]
    curve = [(p["env_steps"], round(p["mean_return"], 1), round(p["median_final_error_deg"], 2)) for p in res.curve]
    print(
        f"curve (env steps, return, median error deg): {curve}; trained: success {trained['success_rate']:.2f}, "
        f"return {trained['mean_return']:.1f}, violations {trained['safety_violations']}, median error "
        f"{trained['median_final_error_deg']:.2f} deg; untrained own design: success {own['success_rate']:.2f}, "
        f"return {own['mean_return']:.1f}, median error {own['median_final_error_deg']:.1f} deg; random designs: "
        f"best success {rand['best_success_rate']:.2f}, best return {rand['best_mean_return']:.1f}; PD on the "
        f"design: {res.summary['pd_baseline']['success_rate']:.2f}"
    )
    assert res.summary["design"]["valid"]
    assert trained["median_final_error_deg"] <= MAX_MEDIAN_ERROR_DEG < own["median_final_error_deg"]
    assert trained["mean_return"] >= MIN_RETURN > max(own["mean_return"], rand["best_mean_return"])
    assert own["success_rate"] == 0.0 and rand["best_success_rate"] == 0.0
    assert res.summary["pd_baseline"]["success_rate"] == 1.0
