"""The `requirements` section of a :class:`~modsat_core.spec.jobspec.JobSpec`: what a satellite must do
and may weigh, stated as an engineer states it (docs/requirements.md).

A design *meets* the requirements when its mass and power are within budget and its own controller, on
the evaluation's held-out slews, lands at least ``success`` of them within ``settling_time_s`` at the
mission's tolerance, nominally and under every flight condition the evaluation flies whose slews lie in
the required range (:func:`judged`; `large-slews` does not judge a satellite required to slew to 90 deg). The slew range
and the pointing tolerance are the mission's: stated here too, they are checked against it, so a run
never claims a requirement it did not fly. :func:`verdict` gives the judgement and every reason.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, model_validator

from modsat_core.spec.evaluation import Condition
from modsat_core.spec.sections import Mission, _Section


class Requirements(_Section):
    """What the satellite must do and may weigh (null fields: no such requirement)."""

    slew_min_deg: float | None = Field(
        None, ge=0.0, le=180.0, description="Smallest slew it must fly; the mission must fly it too."
    )
    slew_max_deg: float | None = Field(
        None, ge=0.0, le=180.0, description="Largest slew it must fly; the mission must fly it too."
    )
    tolerance_deg: float | None = Field(
        None, gt=0.0, le=180.0, description="Pointing tolerance; equal to `mission.tolerance_deg` (checked)."
    )
    settling_time_s: float = Field(
        gt=0.0, le=10_000.0, description="Each landed slew must settle (pointing and rate) within this time, s."
    )
    success: float = Field(
        0.99,
        gt=0.0,
        le=1.0,
        description=(
            "Share of the evaluation's slews that must land within `settling_time_s`, nominally and under each "
            "flight condition of `evaluation.conditions`."
        ),
    )
    mass_budget_kg: float | None = Field(None, gt=0.0, le=100_000.0, description="Largest total mass, kg.")
    power_budget_W: float | None = Field(
        None, gt=0.0, le=100_000.0, description="Largest steady power of the wheels, W (needs their `power_W`)."
    )

    @model_validator(mode="after")
    def _range(self) -> Requirements:
        lo, hi = self.slew_min_deg, self.slew_max_deg
        if lo is not None and hi is not None and lo > hi:
            raise ValueError(f"slew_min_deg ({lo}) must not exceed slew_max_deg ({hi})")
        return self


def judged(condition: Condition, req: Requirements, mission: Mission) -> bool:
    """Whether ``condition`` counts in the verdict: not when it flies slews outside the range the
    requirements ask for, such as `large-slews` for a satellite required to slew to 90 deg (the largest
    is the mission's where they state none; the smallest 0, where they state none: a satellite that
    must slew 90 deg must also make small slews). Such a condition is still flown and reported."""
    lo = req.slew_min_deg if req.slew_min_deg is not None else 0.0
    hi = req.slew_max_deg if req.slew_max_deg is not None else mission.slew_max_deg
    c_lo = condition.slew_min_deg if condition.slew_min_deg is not None else mission.slew_min_deg
    c_hi = condition.slew_max_deg if condition.slew_max_deg is not None else mission.slew_max_deg
    return lo - 1e-9 <= c_lo and c_hi <= hi + 1e-9


def landed_within(episodes: list[dict[str, Any]], settling_time_s: float) -> float:
    """Share of ``episodes`` (monte_carlo rows) that land and settle within ``settling_time_s``."""
    if not episodes:
        return 0.0
    ok = [e for e in episodes if e.get("success") and (e.get("settling_time_s") or 0.0) <= settling_time_s]
    return len(ok) / len(episodes)


def verdict(
    req: Requirements,
    mass_kg: float,
    power_W: float | None,
    shares: dict[str, float],
) -> dict[str, Any]:
    """Whether a design meets ``req``: its ``mass_kg``, ``power_W`` and, per flight (``nominal`` and each
    condition), the share of slews landed within the settling time. Returns ``{"meets", "reasons",
    "mass_kg", "power_W", "landed_within_settling_time"}``; ``reasons`` names every requirement missed."""
    reasons: list[str] = []
    if req.mass_budget_kg is not None and mass_kg > req.mass_budget_kg:
        reasons.append(f"mass {mass_kg:.2f} kg is over the budget of {req.mass_budget_kg:g} kg")
    if req.power_budget_W is not None and (power_W is None or power_W > req.power_budget_W):
        got = "unknown" if power_W is None else f"{power_W:.2f} W"
        reasons.append(f"power {got} is over the budget of {req.power_budget_W:g} W")
    for name, share in shares.items():
        if share < req.success:
            reasons.append(
                f"{name}: {100 * share:.0f} % of the slews settle within {req.settling_time_s:g} s "
                f"(required {100 * req.success:.0f} %)"
            )
    return {
        "meets": not reasons,
        "reasons": reasons,
        "mass_kg": mass_kg,
        "power_W": power_W,
        "landed_within_settling_time": shares,
    }


def requirement_verdict(
    req: Requirements,
    mission: Mission,
    mass_kg: float,
    power_W: float | None,
    nominal: list[dict[str, Any]],
    flights: list[tuple[Condition, list[dict[str, Any]]]],
) -> dict[str, Any]:
    """:func:`verdict` from the slews flown: the ``nominal`` rows and each condition's (``flights``); the
    conditions outside the required slews (:func:`judged`) do not count."""
    limit = req.settling_time_s
    shares = {"nominal": landed_within(nominal, limit)}
    shares.update({c.name: landed_within(eps, limit) for c, eps in flights if judged(c, req, mission)})
    return verdict(req, mass_kg, power_W, shares)
