"""Co-design learns on a cut-down `quick`: a measured outcome, not a loss.

The `quick` preset (set network, the CPU recipe), seed 0, with its budget cut to 10k env
steps so that CI can afford it; its exploration schedules scale with the budget. The
trained policy is compared, on the final evaluation's 32 seeded slews, with what it started
from: the same network untrained flying its own design, and 8 random valid designs flown by
that untrained controller (`modsat_core.baselines.untrained_baselines`). The figures of the
run are in docs/learning.md ("Status"); the margin asserted, 100 above the best baseline, is
far outside the spread of the baselines' returns (all within a few of -169, every slew
breaking the rate limit), so it cannot be reached by a lucky draw of designs.

Success is asserted by tests/learning/test_control_lands.py (the recipe's controller on the
same mission); no co-design run of 10k steps lands slews yet.
"""

from __future__ import annotations

import pytest

from modsat_core.baselines import untrained_baselines
from modsat_core.presets import get_preset
from modsat_core.spec import parse_spec
from modsat_core.train import train

pytestmark = pytest.mark.slow  # trains co-design for 10k env steps (minutes)

MARGIN = 100.0
STEPS = 10_000


def test_codesign_on_quick_beats_the_untrained_policy_and_random_designs():
    d = get_preset("quick").model_dump(mode="json")
    d["training"].update(total_env_steps=STEPS)
    spec = parse_spec(d)
    res = train(spec)
    trained = res.summary["policy"]
    base = untrained_baselines(spec, designs=8)
    own = base["untrained_policy"]["mean_return"]
    rand = base["random_designs"]
    print(
        f"trained {trained['mean_return']:.1f} (violations {trained['safety_violations']}, median error "
        f"{trained['median_final_error_deg']:.1f} deg, success {trained['success_rate']:.2f}); untrained own design "
        f"{own:.1f}; random designs mean {rand['mean_return']:.1f}, best {rand['best_mean_return']:.1f}"
    )
    assert res.summary["design"]["valid"]
    assert trained["mean_return"] >= max(own, rand["best_mean_return"]) + MARGIN
    # Every random design breaks the rate limit on every slew under the untrained controller.
    assert trained["safety_violations"] < min(r["safety_violations"] for r in rand["designs"])
