"""The `evaluation` section of a :class:`~modsat_core.spec.jobspec.JobSpec`, its flight conditions,
and the `randomise` section.

Flight conditions: what a real satellite meets that the model its controller was trained on
does not have (docs/robustness.md).

A :class:`Condition` names a set of departures from the nominal simulation: sensor noise,
actuation delay, an inertia the controller does not know, weaker wheels, a satellite that is
still turning when the slew starts, a disturbance torque, and slews outside the mission's range.
The evaluation flies every condition of ``evaluation.conditions`` with the policy and with PD on
the same slews. The top-level ``randomise`` section (:class:`Randomise`) has the same quantities:
each training slew draws every one uniformly between nominal and the value it gives (domain
randomisation).

The standard conditions (:data:`STANDARD_CONDITIONS`) use magnitudes of a small satellite; the
docs give the source of each number.
"""

from __future__ import annotations

import re
from typing import Any

from pydantic import Field, field_validator, model_validator

from modsat_core.spec.parts import named_items, resolve_named
from modsat_core.spec.sections import _Section

_NAME = re.compile(r"^[a-z0-9][a-z0-9-]{0,39}$")


class Condition(_Section):
    """One set of departures from the nominal flight (all zero / one: the nominal flight)."""

    name: str = Field(
        "custom",
        min_length=1,
        max_length=40,
        description="Lower-case letters, digits and '-'; unique in a list.",
        json_schema_extra={"pattern": _NAME.pattern},
    )
    attitude_noise_deg: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        description=(
            "Std per body axis of the attitude measurement's error (a small rotation of the measured "
            "attitude, drawn afresh every control step)."
        ),
    )
    rate_noise_rad_s: float = Field(
        0.0, ge=0.0, le=1.0, description="Std per body axis of the rate measurement's error, every control step."
    )
    delay_steps: int = Field(
        0,
        ge=0,
        le=10,
        description=(
            "Actuation delay in control steps: the torque applied in step k is the one commanded in "
            "step k - delay_steps (none before the first command)."
        ),
    )
    inertia_scale: float = Field(
        1.0, ge=0.5, le=2.0, description="The true inertia is this times the one the controller knows."
    )
    inertia_rotation_deg: float = Field(
        0.0,
        ge=0.0,
        le=45.0,
        description="The true principal axes are turned by this angle about an axis drawn per slew.",
    )
    torque_fraction: float = Field(
        1.0,
        gt=0.0,
        le=1.0,
        description="Fraction of the commanded torque the wheel units deliver (after the command's clip).",
    )
    tumble_rad_s: float = Field(
        0.0, ge=0.0, le=1.0, description="Body rate at the slew's start, about an axis drawn per slew."
    )
    disturbance_Nm: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        description="A constant body-frame torque about an axis drawn per slew, added to the mission's own.",
    )
    slew_min_deg: float | None = Field(
        None, ge=0.0, le=180.0, description="Smallest slew angle drawn instead of the mission's (null: the mission's)."
    )
    slew_max_deg: float | None = Field(
        None, ge=0.0, le=180.0, description="Largest slew angle drawn instead of the mission's (null: the mission's)."
    )

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not _NAME.fullmatch(v):  # fullmatch: "$" alone would let a trailing newline through
            raise ValueError(f"condition name {v[:60]!r}: use lower-case letters, digits and '-' (at most 40)")
        if v == "nominal":
            raise ValueError("'nominal' names the evaluation's own slews; give the condition another name")
        return v

    @model_validator(mode="after")
    def _slews(self) -> Condition:
        lo, hi = self.slew_min_deg, self.slew_max_deg
        if lo is not None and hi is not None and lo > hi:
            raise ValueError(f"slew_min_deg ({lo}) must not exceed slew_max_deg ({hi})")
        return self

    def changes(self) -> dict[str, Any]:
        """The fields that depart from nominal (what the condition does), name excluded."""
        nominal = Condition()
        return {k: v for k, v in self.model_dump().items() if k != "name" and v != getattr(nominal, k)}


#: Conditions of a small satellite (the 3x3x3 satellites are 0.3 m and 27 kg); docs/robustness.md
#: gives the source of each magnitude.
STANDARD_CONDITIONS: dict[str, Condition] = {
    c.name: c
    for c in (
        Condition(name="sensor-noise", attitude_noise_deg=0.01, rate_noise_rad_s=5e-4),
        Condition(name="delay-1", delay_steps=1),
        Condition(name="inertia-error", inertia_scale=1.1, inertia_rotation_deg=5.0),
        Condition(name="weak-wheels", torque_fraction=0.8),
        Condition(name="tumble", tumble_rad_s=0.05),
        Condition(name="disturbance", disturbance_Nm=1e-4),
        Condition(name="small-slews", slew_min_deg=1.0, slew_max_deg=30.0),
        Condition(name="large-slews", slew_min_deg=150.0, slew_max_deg=180.0),
        Condition(
            name="combined",
            attitude_noise_deg=0.01,
            rate_noise_rad_s=5e-4,
            delay_steps=1,
            inertia_scale=1.1,
            inertia_rotation_deg=5.0,
            torque_fraction=0.8,
            tumble_rad_s=0.05,
            disturbance_Nm=1e-4,
        ),
    )
}


#: Domain randomisation up to the `combined` condition's magnitudes: what the first-order presets
#: train under by default (docs/robustness.md, "Flight-ready by default").
FLIGHT_READY: dict[str, Any] = {
    k: v for k, v in STANDARD_CONDITIONS["combined"].changes().items() if k not in ("slew_min_deg", "slew_max_deg")
}


def resolve_conditions(items: list[Any]) -> list[Any]:
    """A list of conditions where a string names a standard one (``"delay-1"``); unknown names and
    repeated names are errors that list what exists (:func:`~modsat_core.spec.parts.resolve_named`)."""
    return resolve_named(items, STANDARD_CONDITIONS, "condition")


class Randomise(_Section):
    """Domain randomisation: each training slew draws each quantity uniformly between nominal and
    the value given here (an integer delay: each of 0..delay_steps equally likely; the inertia scale
    between ``1 / inertia_scale`` and ``inertia_scale``, so either side of the model). Its fields mean
    what :class:`Condition`'s do; slews outside the mission's range are not drawn in training. All
    nominal (the default of a spec written from scratch): no randomisation. The first-order presets
    set the `combined` condition's magnitudes (:data:`FLIGHT_READY`), so that what they ship flies
    under every standard condition; ``enabled`` false turns it off without listing every field."""

    enabled: bool = Field(
        True,
        description=(
            "false: train on the nominal model whatever the magnitudes below say. The first-order presets "
            "(`quick`, `diffsim-*`) randomise at the `combined` condition's magnitudes by default; "
            '`{"randomise": {"enabled": false}}` in a job\'s overrides trains them nominally.'
        ),
    )

    attitude_noise_deg: float = Field(0.0, ge=0.0, le=10.0, description="Largest attitude noise std drawn.")
    rate_noise_rad_s: float = Field(0.0, ge=0.0, le=1.0, description="Largest rate noise std drawn.")
    delay_steps: int = Field(0, ge=0, le=10, description="Largest actuation delay drawn, control steps.")
    inertia_scale: float = Field(1.0, ge=0.5, le=2.0, description="The inertia scale is drawn between 1/this and this.")
    inertia_rotation_deg: float = Field(0.0, ge=0.0, le=45.0, description="Largest principal-axis rotation drawn.")
    torque_fraction: float = Field(1.0, gt=0.0, le=1.0, description="The torque fraction is drawn between this and 1.")
    tumble_rad_s: float = Field(0.0, ge=0.0, le=1.0, description="Largest initial body rate drawn.")
    disturbance_Nm: float = Field(0.0, ge=0.0, le=10.0, description="Largest disturbance torque drawn.")

    @property
    def active(self) -> bool:
        return self.enabled and self.model_copy(update={"enabled": True}) != Randomise()


class Evaluation(_Section):
    """The Monte-Carlo evaluation: a fixed, seeded set of slews."""

    episodes: int = Field(100, ge=1, le=10_000, description="Slews in the final Monte-Carlo evaluation.")
    seed: int = Field(12345, ge=0, le=2**31 - 1, description="Seed of the slew set (independent of training).")
    trajectories: int = Field(3, ge=0, le=50, description="Episodes whose full time history is kept.")
    conditions: list[Condition] = Field(
        default_factory=lambda: list(STANDARD_CONDITIONS.values()),
        max_length=20,
        json_schema_extra=named_items(list(STANDARD_CONDITIONS)),
        description=(
            "Flight conditions the final evaluation also flies, the policy and PD on the same slews "
            "(docs/robustness.md): objects, or the names of standard ones ("
            + ", ".join(f"`{n}`" for n in STANDARD_CONDITIONS)
            + "). Default: all the standard ones; [] flies the nominal slews only."
        ),
    )
    compiled: bool = Field(
        False,
        description=(
            "Fly the final evaluation (the trade-off's candidates and front, the flight conditions, the kept "
            "design) with the RK4 step fused by torch.compile, in float64 as always: 3.9x the eager step's "
            "speed at 256 slews (`modsat bench sim --compiled --dtype float64`), after a compilation of a "
            "minute or more per process. The numbers agree with the eager step to float64 rounding, not bit "
            "for bit; without a C++ compiler the eager step flies. On in the trade-off presets, whose evaluation "
            "flies a front under every condition: their runs 2x faster (docs/requirements.md)."
        ),
    )
    basilisk: bool = Field(
        False,
        description=(
            "Also fly the evaluation slews in Basilisk beside modsat, with the policy and the PD baseline "
            "(`modsat verify --basilisk`, docs/verification.md); the report is `verification.json`. Needs "
            "Basilisk where the run trains (`pip install -e '.[basilisk]'`); without it the report says so."
        ),
    )

    @field_validator("conditions", mode="before")
    @classmethod
    def _names(cls, v: Any) -> Any:
        return resolve_conditions(v) if isinstance(v, list) else v
