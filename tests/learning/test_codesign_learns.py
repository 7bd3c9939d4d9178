"""Co-design lands the slew: a CI variant of `quick`, success itself asserted.

`quick` as shipped (the set network, the CPU recipe, the design held for the first 20k of
60k env steps) lands seeds 0, 1 and 2 (88-100 % of 100 slews, docs/learning.md) but takes
about an hour on one core: more than CI can give. This variant makes one update per two env
steps (29k updates instead of 58k), everything else as shipped, seed 0: run e35 of
docs/learning.md, "Eighth round" (100 % of the final 32 slews, 97 % of 100; 37 min on the
busy 2-core machine). It is a regression check of that measured run, not a claim about
every seed: seed 1 of this variant does not land (e37), which is why the preset keeps one
update per step.

Its final evaluation (32 seeded slews, 1 deg and 0.01 rad/s at the end of 120 steps) must
land at least `MIN_SUCCESS` of them. Measured against on the same slews: the same network
untrained, flying its own design, and 8 random valid designs flown by that untrained
controller (`modsat_core.baselines.untrained_baselines`), which land none (every slew
breaks the rate limit); and the PD baseline on the designed satellite, which lands all.
"""

from __future__ import annotations

import pytest

from modsat_core.baselines import untrained_baselines
from modsat_core.presets import get_preset
from modsat_core.spec import parse_spec
from modsat_core.train import train

pytestmark = pytest.mark.slow  # trains co-design for 60k env steps (tens of minutes)

#: Share of the final 32 slews that must land. The baselines land none; 24 of 32 by chance
#: would need a controller that points and holds still, which only training gives.
MIN_SUCCESS = 0.75


def test_codesign_on_a_ci_variant_of_quick_lands_most_slews():
    d = get_preset("quick").model_dump(mode="json")
    assert d["seed"] == 0
    d["training"].update(train_frequency=2)
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
