"""The parts catalog: the wheels a wheel unit is built around, the payload, and what a design made of
them weighs and draws (docs/requirements.md). Torch-free: validating a spec never loads torch.

A *wheel unit* is one cube module holding three reaction wheels of one type, one per body axis: it
gives ``torque_Nm`` and stores ``momentum_Nms`` per axis, weighs its housing (``module_mass_kg``, the
structure module's mass) plus three wheels, and draws three wheels' ``power_W``. A catalog
(``modules.wheels``) lists up to :data:`~modsat_core.grid.MAX_WHEEL_TYPES` wheel types; a cell of value
``2 + k`` holds a unit of type ``k``. A payload (``modules.payload``) is a set of fixed cells, each of
its own mass. Without either, a design is what it always was: identical modules of ``module_mass_kg``,
every wheel unit ``torque_scale_Nm`` and ``momentum_capacity_Nms``.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from modsat_core.grid import ACTUATOR, EMPTY, as_grid

_NAME = re.compile(r"^[a-z0-9][a-z0-9.-]{0,39}$")
#: Wheels per wheel unit: one per body axis.
WHEELS_PER_UNIT = 3


class _Part(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class WheelType(_Part):
    """One reaction wheel as its datasheet gives it (a wheel unit holds three, one per body axis)."""

    name: str = Field(
        min_length=1,
        max_length=40,
        description="Lower-case letters, digits, '.' and '-'.",
        json_schema_extra={"pattern": _NAME.pattern},
    )
    torque_Nm: float = Field(gt=0.0, le=10.0, description="Peak torque of one wheel, N m.")
    momentum_Nms: float = Field(gt=0.0, le=1000.0, description="Momentum capacity of one wheel, N m s.")
    mass_kg: float = Field(gt=0.0, le=100.0, description="Mass of one wheel (with its own housing), kg.")
    power_W: float | None = Field(
        None,
        ge=0.0,
        le=1000.0,
        description=(
            "Steady power of one wheel, W (null: not known; a `requirements.power_budget_W` needs it for "
            "every wheel of the catalog)."
        ),
    )
    source: str = Field("", max_length=300, description="Where the figures come from (a datasheet).")

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not _NAME.fullmatch(v):  # fullmatch: "$" alone would let a trailing newline through
            raise ValueError(f"wheel name {v[:60]!r}: use lower-case letters, digits, '.' and '-' (at most 40)")
        return v


_BSK = "Basilisk 2.12.1, utilities/simIncludeRW.py, preset "

#: Real small-satellite wheels, figures as Basilisk's reaction-wheel presets carry them (each preset cites
#: its maker's datasheet; docs/requirements.md lists them). Their steady power is not in those sources, so
#: it is null here: a spec with a power budget gives its wheels' power itself.
WHEEL_LIBRARY: dict[str, WheelType] = {
    w.name: w
    for w in (
        WheelType(
            name="bct-rwp015",
            torque_Nm=0.004,
            momentum_Nms=0.015,
            mass_kg=0.130,
            source=_BSK + "BCT_RWP015 (Blue Canyon Technologies reaction wheel datasheet)",
        ),
        WheelType(
            name="nanoavionics-rw0",
            torque_Nm=0.0032,
            momentum_Nms=0.020,
            mass_kg=0.137,
            source=_BSK + "NanoAvionics_RW0 (NanoAvionics RW0 datasheet; mass with housing)",
        ),
        WheelType(
            name="honeywell-hr12-12",
            torque_Nm=0.2,
            momentum_Nms=12.0,
            mass_kg=6.0,
            source=_BSK + "Honeywell_HR12, 12 N m s option (Honeywell HR12 datasheet)",
        ),
    )
}


def resolve_named(items: list[Any], library: dict[str, Any], kind: str) -> list[Any]:
    """``items`` where a string names an entry of ``library`` (a standard condition, a library wheel):
    unknown names, and names repeated among the entries and the objects, are errors that say what
    exists. Anything else is left to the field's own validation."""
    out: list[Any] = []
    for item in items:
        if isinstance(item, str):
            if item not in library:
                raise ValueError(f"unknown {kind} {item[:60]!r}; known: {', '.join(library)}")
            out.append(library[item])
        else:
            out.append(item)
    names = [getattr(c, "name", None) if not isinstance(c, dict) else c.get("name", "custom") for c in out]
    repeated = sorted({str(n) for n in names if n is not None and names.count(n) > 1})
    if repeated:
        raise ValueError(f"{kind} names must be unique; repeated: {', '.join(repeated)}")
    return out


def named_items(names: list[str]) -> Any:
    """``json_schema_extra`` of a list field whose items are objects or the names of library entries
    (:func:`resolve_named`): the schema says so, with the names it takes."""

    def extra(schema: dict[str, Any]) -> None:
        for node in [schema, *schema.get("anyOf", [])]:
            if node.get("type") == "array" and "items" in node:
                node["items"] = {"anyOf": [node["items"], {"type": "string", "enum": list(names)}]}

    return extra


def resolve_wheels(items: list[Any]) -> list[Any]:
    """A catalog's wheel list where a string names a library wheel (``"bct-rwp015"``)."""
    return resolve_named(items, WHEEL_LIBRARY, "wheel")


#: A cell [i, j, k] (a list: a spec is validated strictly, and JSON has no tuples).
Cell = Annotated[list[Annotated[int, Field(ge=0, le=9)]], Field(min_length=3, max_length=3)]


class Payload(_Part):
    """The payload: fixed cells of the grid, each a module of its own mass, present in every design."""

    cells: list[Cell] = Field(min_length=1, max_length=1000, description="The payload's cells (i, j, k).")
    mass_kg: float = Field(gt=0.0, le=1000.0, description="Mass of each payload cell, kg.")

    @field_validator("cells")
    @classmethod
    def _unique(cls, v: list[list[int]]) -> list[list[int]]:
        if len({tuple(c) for c in v}) != len(v):
            raise ValueError("payload cells must be distinct")
        return v


# ----------------------------------------------------------------------------- a design's figures


class ModuleCatalog(Protocol):
    """What the functions below read of :class:`~modsat_core.spec.sections.ModuleCatalog` (which imports
    this module, so it is named here by its fields)."""

    @property
    def module_mass_kg(self) -> float: ...
    @property
    def torque_scale_Nm(self) -> float: ...
    @property
    def momentum_capacity_Nms(self) -> float | None: ...
    @property
    def wheels(self) -> list[WheelType] | None: ...
    @property
    def payload(self) -> Payload | None: ...


def unit_mass_kg(modules: ModuleCatalog, k: int) -> float:
    """Mass of a wheel unit of the catalog's type ``k``: its housing and three wheels (without a
    catalog: ``module_mass_kg``)."""
    if not modules.wheels:
        return modules.module_mass_kg
    return modules.module_mass_kg + WHEELS_PER_UNIT * modules.wheels[k].mass_kg


def cell_masses(design: Any, modules: ModuleCatalog) -> np.ndarray:
    """(N, N, N) float64: each cell's mass, kg (0 where empty): structure ``module_mass_kg``, a wheel
    unit its type's (:func:`unit_mass_kg`), a payload cell the payload's."""
    grid = as_grid(design)
    out = np.where(grid != EMPTY, modules.module_mass_kg, 0.0)
    if modules.wheels:
        for k in range(len(modules.wheels)):
            out[grid == ACTUATOR + k] = unit_mass_kg(modules, k)
    if modules.payload is not None:
        for cell in modules.payload.cells:
            c = (cell[0], cell[1], cell[2])
            if max(c) < grid.shape[0] and grid[c] != EMPTY:
                out[c] = modules.payload.mass_kg
    return out


def unit_limits(types: np.ndarray, modules: ModuleCatalog) -> tuple[np.ndarray, np.ndarray]:
    """The per-axis torque (N m) and momentum capacity (N m s; inf: unlimited) of wheel units of cell
    types ``types`` (K,), each >= 2."""
    t = np.asarray(types, dtype=np.int64) - ACTUATOR
    if not modules.wheels:
        cap = modules.momentum_capacity_Nms
        return np.full(len(t), modules.torque_scale_Nm), np.full(len(t), np.inf if cap is None else cap)
    torque = np.array([w.torque_Nm for w in modules.wheels])
    momentum = np.array([w.momentum_Nms for w in modules.wheels])
    return torque[t], momentum[t]


def design_power_W(design: Any, modules: ModuleCatalog) -> float | None:
    """Steady power of a design's wheels, W (null without a catalog, whose wheel units state none, and
    where a wheel the design carries has no power figure)."""
    grid = as_grid(design)
    if not modules.wheels:
        return None
    total = 0.0
    for k, w in enumerate(modules.wheels):
        n = int((grid == ACTUATOR + k).sum())
        if n and w.power_W is None:
            return None
        total += n * WHEELS_PER_UNIT * (w.power_W or 0.0)
    return total


def design_mass_kg(design: Any, modules: ModuleCatalog) -> float:
    return float(cell_masses(design, modules).sum())
