"""Co-design learns on the `quick` preset: a measured outcome, not a loss.

The trained policy (the `quick` preset as it ships, seed 0, 30k env steps) is compared
with what it started from, on the final evaluation's 32 seeded slews: the same network
untrained flying its own design, and 8 random valid designs flown by that untrained
controller (`modsat_core.baselines.untrained_baselines`).

Measured at commit time (docs/learning.md, "Status"): the baselines average -167.0 (best
random design -165.2, every slew a rate-limit violation; the untrained network's own design
is invalid, -170); the trained runs end at +42.1 / -72.9 / -8.8 on seeds 0 / 1 / 2. The
margin asserted here, 50 above the best baseline, is about 20 times the spread of the
baselines' returns, so it cannot be reached by a lucky draw of designs.

Success is not asserted: no `quick` run has reached the 1 deg / 0.01 rad/s settle condition
in its 30k-step budget (docs/learning.md says what it takes), so "trained success > untrained
success" would fail.
"""

from __future__ import annotations

from modsat_core.baselines import untrained_baselines
from modsat_core.presets import get_preset
from modsat_core.train import train

MARGIN = 50.0


def test_codesign_on_quick_beats_the_untrained_policy_and_random_designs():
    spec = get_preset("quick")
    res = train(spec)
    trained = res.summary["policy"]
    base = untrained_baselines(spec, designs=8)
    own = base["untrained_policy"]["mean_return"]
    rand = base["random_designs"]
    print(f"trained {trained['mean_return']:.1f} (violations {trained['safety_violations']}, median error "
          f"{trained['median_final_error_deg']:.1f} deg, success {trained['success_rate']:.2f}); untrained own design "
          f"{own:.1f}; random designs mean {rand['mean_return']:.1f}, best {rand['best_mean_return']:.1f}")
    assert res.summary["design"]["valid"]
    assert trained["mean_return"] >= max(own, rand["best_mean_return"]) + MARGIN
    # Every random design breaks the rate limit on every slew under the untrained controller.
    assert trained["safety_violations"] < min(r["safety_violations"] for r in rand["designs"])
