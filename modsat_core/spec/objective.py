"""The `objective` section of a :class:`~modsat_core.spec.jobspec.JobSpec`: what a designed
satellite costs, for the design learner of `diffsim-codesign` (docs/diffsim.md, "Co-design").

A design's objective, in seconds (lower is better), is the mean over its slews of the settling
time (the whole episode, ``mission.episode_steps * control_dt_s``, for a slew that does not land
or breaks the rate limit) plus ``module_price_s`` per module and ``wheel_price_s`` more per wheel
unit. Payload cells must hold a structure module: the design learner never changes them, and
the satellite is the part of the design face-connected to them. The paper presets do not use
this section: their objective is the paper's reward.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, field_validator

from modsat_core.spec.sections import _Section

_Index = Annotated[int, Field(ge=0, le=9)]


class Objective(_Section):
    """Prices of a design in seconds of slew time, and its payload (`diffsim-codesign`)."""

    module_price_s: float = Field(
        0.0, ge=0.0, le=1000.0, description="Seconds of slew time a module (of any type) is worth not carrying."
    )
    wheel_price_s: float = Field(
        0.0, ge=0.0, le=1000.0, description="Seconds more for a module that is a wheel unit (its cost, power, mass)."
    )
    mass_price_s_per_kg: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        description=(
            "Seconds of slew time a kilogram is worth not carrying: the design's mass from the parts catalog "
            "(`modules`: structure, each wheel unit type, the payload), added to the module and wheel prices."
        ),
    )
    trade_off_prices_s_per_kg: list[Annotated[float, Field(ge=0.0, le=1000.0)]] = Field(
        default_factory=list,
        max_length=12,
        description=(
            "`diffsim-codesign`: mass prices (s per kg), one design distribution each, all flown by one controller; "
            "the run returns the Pareto front of flown designs over mass and median settling time and keeps the "
            "lightest that meets `requirements` (docs/requirements.md). Empty: one distribution, one design, "
            "priced by `mass_price_s_per_kg`."
        ),
    )
    payload_cells: list[tuple[_Index, _Index, _Index]] = Field(
        default_factory=list,
        max_length=1000,
        description=(
            "Cells [i, j, k] that hold the payload: structure modules the design always has, "
            "face-connected to each other. Empty: the design grows from the centre cell, an actuator."
        ),
    )

    @field_validator("trade_off_prices_s_per_kg")
    @classmethod
    def _prices(cls, v: list[float]) -> list[float]:
        if len(v) == 1:
            raise ValueError("a trade-off needs at least two prices (one is `mass_price_s_per_kg`)")
        if len(set(v)) != len(v):
            raise ValueError("trade_off_prices_s_per_kg must be distinct")
        return sorted(v)

    @field_validator("payload_cells")
    @classmethod
    def _distinct(cls, v: list[tuple[int, int, int]]) -> list[tuple[int, int, int]]:
        if len(set(v)) != len(v):
            raise ValueError("payload_cells must be distinct")
        return v
