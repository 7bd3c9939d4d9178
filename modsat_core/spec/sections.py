"""The physical sections of a :class:`~modsat_core.spec.jobspec.JobSpec`: the design space, the
module catalogue, the mission and its reward. Same rules as the spec: SI units in the field
names, every number bounded, unknown keys rejected.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from modsat_core.grid import MAX_CELL, MAX_WHEEL_TYPES, validity_problem
from modsat_core.spec.parts import WHEEL_LIBRARY, Payload, WheelType, named_items, resolve_wheels

# Numbers that appear in several places of the spec.
PAPER_TAU_3X3X3_NM = 0.8
PAPER_TAU_5X5X5_NM = 1.5


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


Vec3 = tuple[
    Annotated[float, Field(ge=-10.0, le=10.0)],
    Annotated[float, Field(ge=-10.0, le=10.0)],
    Annotated[float, Field(ge=-10.0, le=10.0)],
]


# Nested lists of cell types, at most 10 deep on each axis (the largest grid).
_Cell = Annotated[int, Field(ge=0, le=MAX_CELL)]
DesignGrid = Annotated[
    list[Annotated[list[Annotated[list[_Cell], Field(max_length=10)]], Field(max_length=10)]],
    Field(max_length=10),
]


class DesignSpace(_Section):
    """The morphology search space: an N x N x N grid of cube modules."""

    grid_size: int = Field(3, ge=2, le=10, description="N: the design grid is N x N x N cells.")
    design_steps: int = Field(
        10, ge=1, le=50, description="Synchronous NCA update steps from the seed module (design phase)."
    )
    fixed_design: DesignGrid | None = Field(
        None,
        description=(
            "A given morphology (N x N x N nested lists of 0 empty, 1 structure, 2 actuator; with "
            "`modules.wheels`, 2 + k is a wheel unit of the catalog's k-th wheel). "
            "Required by `td3-control`, which trains a controller for this design only."
        ),
    )
    repair: bool = Field(
        False,
        description=(
            "Make every grown design valid: after the last design step the seed cell becomes an "
            "actuator and modules not face-connected to it are removed. Off in the paper, which "
            "penalises invalid designs (`invalid_penalty`) instead."
        ),
    )
    invalid_penalty: float = Field(
        -100.0,
        ge=-1e6,
        le=0.0,
        description=(
            "Return of an episode whose design is invalid. It is clamped below the worst "
            "return any valid design can get, so an invalid design is never preferred."
        ),
    )

    @field_validator("fixed_design")
    @classmethod
    def _check_fixed_design(cls, v: list[list[list[int]]] | None, info: Any) -> list[list[list[int]]] | None:
        if v is None:
            return v
        n = info.data.get("grid_size")
        if n is None:
            return v
        if len(v) != n or any(len(row) != n for row in v) or any(len(c) != n for row in v for c in row):
            raise ValueError(f"fixed_design must be a {n} x {n} x {n} nested list (grid_size is {n})")
        problem = validity_problem(v)
        if problem:
            raise ValueError(f"fixed_design is not a valid satellite: {problem}")
        return v


class ModuleCatalog(_Section):
    """Physical properties of the cube modules (paper: 1.0 kg, 0.1 m cubes)."""

    module_mass_kg: float = Field(1.0, gt=0.0, le=1000.0, description="Mass of every module.")
    module_size_m: float = Field(0.1, gt=0.0, le=10.0, description="Edge length of the cube modules.")
    torque_scale_Nm: float = Field(
        PAPER_TAU_3X3X3_NM,
        gt=0.0,
        le=100.0,
        description="Per-axis torque limit of one actuator module (the paper's torque scale).",
    )
    actuator_model: Literal["ideal-torque", "reaction-wheel"] = Field(
        "reaction-wheel",
        description=(
            "`ideal-torque`: the control torque acts directly on the body, no momentum state "
            "(reproduces the paper). `reaction-wheel`: each actuator module is a 3-axis wheel "
            "unit that stores the momentum it takes from the body."
        ),
    )
    momentum_capacity_Nms: float | None = Field(
        None,
        gt=0.0,
        le=1000.0,
        description=(
            "Per-axis momentum capacity of one wheel unit; a wheel at capacity cannot "
            "accelerate further in that direction. null = unlimited. Only for `reaction-wheel`."
        ),
    )
    wheels: list[WheelType] | None = Field(
        None,
        max_length=MAX_WHEEL_TYPES,
        json_schema_extra=named_items(list(WHEEL_LIBRARY)),
        description=(
            "The parts catalog's wheel types (docs/requirements.md): objects, or the names of library wheels ("
            + ", ".join(f"`{n}`" for n in WHEEL_LIBRARY)
            + "). A wheel unit holds three wheels of one type; a design cell of 2 + k is a unit of the k-th. "
            "With a catalog, `torque_scale_Nm` and `momentum_capacity_Nms` are the strongest wheel's (set for "
            "you). null: one wheel unit type, `torque_scale_Nm` and `momentum_capacity_Nms`, weighing "
            "`module_mass_kg`."
        ),
    )
    payload: Payload | None = Field(
        None,
        description=(
            "Fixed payload cells, each of its own mass, present in every design (co-design keeps them; null: none)."
        ),
    )

    @field_validator("wheels", mode="before")
    @classmethod
    def _library(cls, v: Any) -> Any:
        return resolve_wheels(v) if isinstance(v, list) else v

    @model_validator(mode="before")
    @classmethod
    def _from_catalog(cls, data: Any) -> Any:
        """With wheels, the per-unit torque and momentum scales are the strongest wheel's."""
        if not isinstance(data, dict) or not isinstance(data.get("wheels"), list) or not data["wheels"]:
            return data
        try:
            wheels = [
                w if isinstance(w, WheelType) else WheelType.model_validate(w) for w in resolve_wheels(data["wheels"])
            ]
        except (ValueError, TypeError):
            return data  # the field's own validation reports it
        tau = max(w.torque_Nm for w in wheels)
        cap = max(w.momentum_Nms for w in wheels)
        for key, value in (("torque_scale_Nm", tau), ("momentum_capacity_Nms", cap)):
            given = data.get(key)
            if given is not None and not math.isclose(float(given), value, rel_tol=1e-9):
                raise ValueError(
                    f"{key} is the strongest catalog wheel's ({value:g}) when `wheels` is given; "
                    f"leave it out (got {given})"
                )
        return {**data, "torque_scale_Nm": tau, "momentum_capacity_Nms": cap}

    @model_validator(mode="after")
    def _catalog_needs_wheels(self) -> ModuleCatalog:
        if self.wheels is not None and not self.wheels:
            raise ValueError("wheels: give at least one wheel type, or null for the single unit type")
        if self.wheels and self.actuator_model != "reaction-wheel":
            raise ValueError("a wheel catalog (`wheels`) needs actuator_model `reaction-wheel`")
        return self


class RewardSpec(_Section):
    """Shaped reward with safety constraint (Elkins et al. 2020)."""

    error_scale_rad: float = Field(
        0.14 * 2 * math.pi, gt=0.0, le=10.0, description="phi scale of the exp(-phi/scale) term."
    )
    no_progress_penalty: float = Field(
        1.0, ge=0.0, le=100.0, description="Subtracted when the error angle did not decrease."
    )
    in_tolerance_bonus: float = Field(9.0, ge=0.0, le=1000.0, description="Added while phi <= tolerance.")
    no_progress_penalty_in_tolerance: bool = Field(
        True,
        description=(
            "Charge `no_progress_penalty` inside the tolerance cone too (the paper's reward). There a "
            "satellite held still never decreases phi and pays it on every step, while one that "
            "oscillates pays it on about half: the reward prefers chattering to holding. `false` "
            "charges it only outside the cone."
        ),
    )
    settle_bonus: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        description=(
            "Added while phi <= tolerance, times exp(-|omega| / `settle_rate_scale_rad_s`): a "
            "continuous reward for being still inside the cone (0: the paper's reward)."
        ),
    )
    settle_rate_scale_rad_s: float = Field(
        0.05,
        gt=0.0,
        le=10.0,
        description=(
            "Rate scale of `settle_bonus`. Wider than the rate tolerance on purpose: a policy that "
            "chatters at 0.1 rad/s must still see the term grow as it slows down."
        ),
    )
    bonus_needs_settled: bool = Field(
        False,
        description=(
            "Pay `in_tolerance_bonus` only while the body rate is also at most "
            "`mission.rate_tolerance_rad_s`, the success condition, rather than whenever phi is "
            "within tolerance (the paper's reward, which pays a controller that chatters through "
            "the tolerance cone as much as one that holds still in it)."
        ),
    )
    rate_margin_penalty: float = Field(
        0.0,
        ge=0.0,
        le=100.0,
        description=(
            "Subtracted on every step whose body rate is above `rate_margin_fraction` of the rate limit, "
            "times how far into that margin it is (0 at its start, 1 at the limit): a slope before the "
            "limit's cliff, so that a policy cruising at the limit learns to keep off it (0: the paper's "
            "reward, which only ends the episode at the limit)."
        ),
    )
    rate_margin_fraction: float = Field(
        0.9, gt=0.0, lt=1.0, description="Where `rate_margin_penalty` starts, as a fraction of the rate limit."
    )
    safety_penalty: float = Field(
        50.0, ge=0.0, le=1e4, description="Subtracted once when the rate limit is exceeded (episode ends)."
    )
    safety_penalty_per_remaining_step: float = Field(
        0.0,
        ge=0.0,
        le=100.0,
        description=(
            "Also subtracted, on a violation, for every control step the episode had left. "
            "At `no_progress_penalty` or more, ending the episode early is never cheaper than "
            "holding still (a fixed -50 is, with more than 50 to 110 steps left)."
        ),
    )


class Mission(_Section):
    """Large-angle slew then hold, with the paper's integration settings."""

    slew_min_deg: float = Field(30.0, ge=0.0, le=180.0, description="Smallest slew angle drawn.")
    slew_max_deg: float = Field(150.0, ge=0.0, le=180.0, description="Largest slew angle drawn.")
    tolerance_deg: float = Field(0.25, gt=0.0, le=180.0, description="Pointing tolerance for success.")
    rate_tolerance_rad_s: float = Field(
        0.01, gt=0.0, le=10.0, description="Body rate below which the satellite counts as settled."
    )
    rate_limit_rad_s: float = Field(
        0.5, gt=0.0, le=10.0, description="Safety limit on |omega|; exceeding it ends the episode."
    )
    physics_dt_s: float = Field(1.0 / 240.0, gt=0.0, le=1.0, description="RK4 step.")
    frame_skip: int = Field(20, ge=1, le=1000, description="Physics steps per control step.")
    episode_steps: int = Field(500, ge=1, le=100_000, description="Control steps per episode.")
    orbit_altitude_km: float = Field(500.0, ge=100.0, le=100_000.0, description="Circular orbit altitude.")
    gravity_gradient: bool = Field(True, description="Apply the gravity-gradient torque.")
    residual_torque_Nm: Vec3 = Field((0.0, 0.0, 0.0), description="Constant body-frame disturbance torque.")
    residual_torque_std_Nm: float = Field(
        0.0, ge=0.0, le=10.0, description="Std of a random constant body-frame torque drawn per episode."
    )
    reward: RewardSpec = Field(default_factory=RewardSpec)

    @model_validator(mode="after")
    def _check_range(self) -> Mission:
        if self.slew_min_deg > self.slew_max_deg:
            raise ValueError(f"slew_min_deg ({self.slew_min_deg}) must not exceed slew_max_deg ({self.slew_max_deg})")
        return self

    @property
    def control_dt_s(self) -> float:
        return self.physics_dt_s * self.frame_skip


class GA(_Section):
    """Genetic-algorithm baseline (Evolution Gym style): each design gets its own controller."""

    inner: Literal["td3", "diffsim"] = Field(
        "td3",
        description=(
            "The learner of each design's controller: `td3` (the paper's: TD3 with the `training` "
            "section's settings) or `diffsim` (the first-order learner with the `diffsim` section's, "
            "`diffsim-control`). Its budget is `steps_per_design` env steps."
        ),
    )
    fitness: Literal["return", "objective"] = Field(
        "return",
        description=(
            "A design's fitness: `return`, its inner controller's best curve return (the paper's); "
            "`objective`, minus its `objective` (seconds, docs/diffsim.md) flown by that controller on "
            "`diffsim.design_slews` slews. With `objective.payload_cells` every design carries the payload."
        ),
    )
    population_size: int = Field(12, ge=2, le=1000, description="Designs per generation.")
    survivor_start: float = Field(0.6, ge=0.0, le=1.0, description="Survivor fraction at the start of the budget.")
    survivor_end: float = Field(0.0, ge=0.0, le=1.0, description="Survivor fraction at the end of the budget.")
    mutation_rate: float = Field(0.1, ge=0.0, le=1.0, description="Probability that a cell changes type.")
    steps_per_design: int = Field(
        50_000, ge=1, le=100_000_000, description="Env steps of the inner learner for each new design."
    )
