"""Co-design lands the slew: `quick-td3` (TD3 co-design on the demo mission), success itself asserted.

`quick-td3` (the set network, `cpu-3x3x3`'s recipe, 15k env steps, seed 0) is run q2s0 of
docs/lab/2026-12-04-design-trust-region-quick-5x5x5.md: 28 of its final 32 slews (1 deg and 0.01 rad/s at the
end of 120 steps) landed, 91 of 100 with `modsat eval`, after 9.4 min of training on one core.
It is a regression check of that measured run, not a claim about every seed: seeds 1 and 2
land 61 % and 0 % of 100 in this budget, and a machine with other floating point (another
SIMD width) is another draw of the same recipe.

Its final evaluation (32 seeded slews) must land at least `MIN_SUCCESS` of them. Measured
against on the same slews: the same network untrained, flying its own design, and 8 random
valid designs flown by that untrained controller (`tests.learning.baselines.untrained_baselines`),
which land none (every slew breaks the rate limit or ends far off); and the PD baseline on the
designed satellite, which lands all.
"""

from __future__ import annotations

import pytest

from modsat_core.spec.jobspec import parse_spec
from modsat_core.spec.presets import get_preset
from modsat_core.training.train import train
from tests.learning.baselines import untrained_baselines

from .conftest import on_the_measured_cpu

pytestmark = [pytest.mark.slow, on_the_measured_cpu]  # trains co-design for 15k env steps (about 10 minutes)

#: Share of the final 32 slews that must land (the measured run: 28). The baselines land none;
#: 16 of 32 by chance would need a controller that points and holds still, which only training
#: gives. Half, not three quarters: the run's curve swings (47, 6, 47, 88 % at 7.5k-15k), so a
#: draw on other floating point lands less than the measured one.
MIN_SUCCESS = 0.5


def test_codesign_on_quick_lands_the_slew():
    d = get_preset("quick-td3").model_dump(mode="json")
    assert d["seed"] == 0
    spec = parse_spec(d)
    res = train(spec)
    trained = res.summary["policy"]
    base = untrained_baselines(spec, designs=8)
    own, rand = base["untrained_policy"], base["random_designs"]
    print(
        f"trained: success {trained['success_rate']:.2f}, return {trained['mean_return']:.1f}, violations "
        f"{trained['safety_violations']}, median error {trained['median_final_error_deg']:.2f} deg; untrained own "
        f"design: success {own['success_rate']:.2f}, return {own['mean_return']:.1f}; random designs: best success "
        f"{rand['best_success_rate']:.2f}, best return {rand['best_mean_return']:.1f}; PD on the design: "
        f"{res.summary['pd_baseline']['success_rate']:.2f}"
    )
    assert res.summary["design"]["valid"]
    assert trained["success_rate"] >= MIN_SUCCESS
    assert own["success_rate"] == 0.0 and rand["best_success_rate"] == 0.0
    assert res.summary["pd_baseline"]["success_rate"] == 1.0
