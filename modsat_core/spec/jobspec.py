"""`JobSpec`: the one typed description of a modsat run.

The API, the worker, the CLI and the web form all read and write this model. Every
number is bounded, unknown keys are rejected (``extra="forbid"``), and
:func:`parse_spec` turns pydantic's errors into messages that name the field, the value
and the allowed range.

Units are SI and are part of the field names where they matter (``_deg``, ``_Nm``...).
"""

from __future__ import annotations

import functools
import json
from typing import Any, Literal

from pydantic import Field, ValidationError, model_validator
from pydantic_core import ErrorDetails

from modsat_core.grid import is_connected
from modsat_core.spec.diffsim import Diffsim
from modsat_core.spec.evaluation import Evaluation, Randomise
from modsat_core.spec.objective import Objective
from modsat_core.spec.parts import WHEELS_PER_UNIT, unit_mass_kg
from modsat_core.spec.requirements import Requirements
from modsat_core.spec.sections import GA, DesignSpace, Mission, ModuleCatalog, RewardSpec, _Section
from modsat_core.spec.training import Training

__all__ = [
    "GA",
    "DesignSpace",
    "Diffsim",
    "Evaluation",
    "JobSpec",
    "Mission",
    "ModuleCatalog",
    "Objective",
    "RewardSpec",
    "SpecError",
    "Training",
    "UnrunnableSpec",
    "format_errors",
    "parse_spec",
    "spec_error",
    "spec_errors",
]

SPEC_VERSION: Literal[1] = 1


class JobSpec(_Section):
    """A whole run: what to optimise, on which mission, with which budget."""

    version: Literal[1] = SPEC_VERSION
    name: str | None = Field(None, max_length=200, description="A label for people; not used by the run.")
    algorithm: Literal["td3-codesign", "ga", "td3-control", "diffsim-control", "diffsim-codesign"] = Field(
        "td3-codesign",
        description="`td3-codesign`: NCA design + control by TD3 (paper). `ga`: GA over designs with TD3 "
        "inner loops. `td3-control`: TD3 control of `design.fixed_design`. `diffsim-control`: control of "
        "`design.fixed_design` learned by backpropagating a mission cost through the simulator (`diffsim`). "
        "`diffsim-codesign`: a design distribution learned by policy gradient on `objective`, flown by a "
        "design-conditioned `diffsim` controller trained on its designs.",
    )
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seeds networks, exploration and training slews.")
    design: DesignSpace = Field(default_factory=DesignSpace)
    modules: ModuleCatalog = Field(default_factory=ModuleCatalog)
    mission: Mission = Field(default_factory=Mission)
    training: Training = Field(default_factory=Training)
    ga: GA = Field(default_factory=GA)
    evaluation: Evaluation = Field(default_factory=Evaluation)
    diffsim: Diffsim = Field(default_factory=Diffsim)
    objective: Objective = Field(default_factory=Objective)
    randomise: Randomise = Field(default_factory=Randomise)
    requirements: Requirements | None = Field(
        None,
        description=(
            "What the satellite must do and may weigh (docs/requirements.md); the final evaluation says whether "
            "the run's design and controller meet it. null: no requirements."
        ),
    )

    @model_validator(mode="after")
    def _check_consistency(self) -> JobSpec:
        self._check_catalog()
        N, payload = self.design.grid_size, self.objective.payload_cells
        outside = next((c for c in payload if max(c) >= N), None)
        if outside is not None:
            raise ValueError(f"objective.payload_cells: {list(outside)} is outside the {N}^3 grid")
        if payload and not is_connected(_payload_grid(payload, N)):
            raise ValueError("objective.payload_cells must be face-connected: the payload is one piece")
        if self.algorithm in ("td3-control", "diffsim-control") and self.design.fixed_design is None:
            raise ValueError(f"algorithm {self.algorithm!r} needs design.fixed_design")
        if self.modules.momentum_capacity_Nms is not None and self.modules.actuator_model != "reaction-wheel":
            raise ValueError("modules.momentum_capacity_Nms is only meaningful with actuator_model 'reaction-wheel'")
        return self

    def _check_catalog(self) -> None:
        """The parts catalog against the grid, the algorithm and the requirements."""
        m, N = self.modules, self.design.grid_size
        types = len(m.wheels) if m.wheels else 1
        fixed = self.design.fixed_design
        if fixed is not None:
            top = max(c for plane in fixed for row in plane for c in row)
            if top >= 2 + types:
                raise ValueError(
                    f"design.fixed_design has a cell of type {top}, a wheel unit of type {top - 2}; "
                    f"modules.wheels lists {types} type{'s' * (types != 1)} (cells 2..{1 + types})"
                )
        if m.payload is not None:
            outside = next((c for c in m.payload.cells if max(c) >= N), None)
            if outside is not None:
                raise ValueError(f"modules.payload.cells: {list(outside)} is outside the {N}^3 grid")
            if not is_connected(_payload_grid([(c[0], c[1], c[2]) for c in m.payload.cells], N)):
                raise ValueError("modules.payload.cells must be face-connected: the payload is one piece")
            obj = self.objective.payload_cells
            if obj and sorted(obj) != sorted((c[0], c[1], c[2]) for c in m.payload.cells):
                raise ValueError("objective.payload_cells and modules.payload.cells name different cells; give one")
        if (m.wheels or m.payload is not None) and self.algorithm not in ("diffsim-control", "diffsim-codesign"):
            raise ValueError(
                f"modules.wheels and modules.payload (the parts catalog) fly with the first-order learner "
                f"(`diffsim-control`, `diffsim-codesign`), not {self.algorithm!r}"
            )
        if self.objective.trade_off_prices_s_per_kg and (
            self.algorithm != "diffsim-codesign" or self.diffsim.design_gradient != "score-function"
        ):
            raise ValueError(
                "objective.trade_off_prices_s_per_kg: the trade-off is a `diffsim-codesign` run with the "
                "`score-function` design gradient"
            )
        if m.wheels and self.algorithm == "diffsim-codesign" and self.diffsim.design_gradient == "relaxed":
            raise ValueError("diffsim.design_gradient `relaxed` relaxes one wheel unit type: leave modules.wheels out")
        r = self.requirements
        if r is not None:
            for key, got in (("slew_max_deg", self.mission.slew_max_deg), ("slew_min_deg", self.mission.slew_min_deg)):
                want = getattr(r, key)
                if want is not None and (got < want if key == "slew_max_deg" else got > want):
                    raise ValueError(
                        f"requirements.{key} ({want:g}) is outside the slews the mission flies "
                        f"(mission.{key} {got:g}): the run could not show it"
                    )
            if r.tolerance_deg is not None and self.mission.tolerance_deg > r.tolerance_deg:
                raise ValueError(
                    f"requirements.tolerance_deg ({r.tolerance_deg:g}) is tighter than mission.tolerance_deg "
                    f"({self.mission.tolerance_deg:g}), the tolerance the run is judged at; make them equal"
                )
            self._check_reachable(r)
            if r.power_budget_W is not None and not (m.wheels and all(w.power_W is not None for w in m.wheels)):
                raise ValueError(
                    "requirements.power_budget_W needs modules.wheels with every wheel's power_W "
                    "(the library's wheels carry none: give each its datasheet's steady power)"
                )

    def _check_reachable(self, r: Requirements) -> None:
        """A budget below the lightest satellite the grid can hold (the payload and one wheel unit of the
        lightest, least power-hungry type) is refused: no design could meet it."""
        m = self.modules
        # the payload: the catalog's cells at their mass, else the objective's as structure (when both are
        # given they are the same cells, checked above)
        if m.payload is not None:
            payload = m.payload.mass_kg * len(m.payload.cells)
        else:
            payload = m.module_mass_kg * len(self.objective.payload_cells)
        unit = min(unit_mass_kg(m, k) for k in range(len(m.wheels) if m.wheels else 1))
        if r.mass_budget_kg is not None and r.mass_budget_kg < payload + unit:
            raise ValueError(
                f"requirements.mass_budget_kg ({r.mass_budget_kg:g} kg) is below the lightest satellite the grid "
                f"can hold ({payload + unit:.3g} kg: the payload and one wheel unit): no design can meet it"
            )
        if r.power_budget_W is not None and m.wheels and all(w.power_W is not None for w in m.wheels):
            least = min(WHEELS_PER_UNIT * (w.power_W or 0.0) for w in m.wheels)
            if r.power_budget_W < least:
                raise ValueError(
                    f"requirements.power_budget_W ({r.power_budget_W:g} W) is below one wheel unit's steady power "
                    f"({least:.3g} W): no design can meet it"
                )


def _payload_grid(cells: list[tuple[int, int, int]], N: int) -> list:
    grid = [[[0] * N for _ in range(N)] for _ in range(N)]
    for i, j, k in cells:
        grid[i][j][k] = 1
    return grid


def is_diffsim(spec: JobSpec) -> bool:
    """Whether ``spec``'s controllers are the first-order learner's (its policy, its memory, its
    trainer): `diffsim-control`, `diffsim-codesign`, and the GA with `ga.inner` `diffsim`."""
    return spec.algorithm in ("diffsim-control", "diffsim-codesign") or (
        spec.algorithm == "ga" and spec.ga.inner == "diffsim"
    )


class UnrunnableSpec(ValueError):
    """A valid spec that cannot run where it was sent (e.g. ``device: cuda`` without a GPU).
    Retrying cannot help: a worker fails the job at once."""


class SpecError(ValueError):
    """A spec that failed validation; ``messages`` has one readable line per problem (at most
    :data:`MAX_ERRORS` of them, ``errors`` the same ones), ``omitted`` how many more there were."""

    def __init__(self, messages: list[str], errors: list[ErrorDetails] | None = None, omitted: int = 0):
        self.messages = messages
        self.errors = errors or []
        self.omitted = omitted
        more = [f"... and {omitted} more problems of the same spec, not listed"] if omitted else []
        super().__init__("invalid spec:\n  " + "\n  ".join(messages + more))


#: Problems of one spec that are listed (a 10^3 grid of nulls has 1,000): the rest are counted.
MAX_ERRORS = 20
#: Characters of a value sent that an error message quotes; a longer one is cut and its length given.
MAX_QUOTED = 80


def quote(value: Any, limit: int = MAX_QUOTED) -> str:
    """``value`` as an error message shows it: its repr, cut to ``limit`` characters (an error never
    echoes a long request back); an object is ``{...}``."""
    if isinstance(value, dict):
        return "{...}"
    text = repr(value)
    if len(text) <= limit:
        return text
    size = f"{len(value)} characters" if isinstance(value, str) else f"{len(text)} characters as text"
    return f"{text[:limit]}... ({size})"


@functools.cache
def _spec_schema() -> dict[str, Any]:
    """JobSpec's JSON schema, built once: building it takes ~80 ms, and an error message looks it up
    per problem (a 1,000-problem body took 40 s when it was built per problem)."""
    return JobSpec.model_json_schema()


@functools.lru_cache(maxsize=1024)
def _field_schema(loc: tuple[Any, ...]) -> dict[str, Any] | None:
    """The JSON-schema node of the field at ``loc`` (resolving $refs), or None. Read only."""
    schema = _spec_schema()
    defs = schema.get("$defs", {})
    node: dict[str, Any] = schema
    for part in loc:
        while "$ref" in node:
            node = defs[node["$ref"].rsplit("/", 1)[-1]]
        if "anyOf" in node:  # Optional[...]: take the non-null branch
            node = next((n for n in node["anyOf"] if n.get("type") != "null"), node)
            while "$ref" in node:
                node = defs[node["$ref"].rsplit("/", 1)[-1]]
        if isinstance(part, int):
            if "items" in node:
                node = node["items"]
            elif "prefixItems" in node and part < len(node["prefixItems"]):
                node = node["prefixItems"][part]
            else:
                return None
        else:
            props = node.get("properties", {})
            if part not in props:
                return None
            node = props[part]
    while "$ref" in node:
        node = defs[node["$ref"].rsplit("/", 1)[-1]]
    return node


def _range_text(node: dict[str, Any]) -> str | None:
    lo = node.get("minimum", node.get("exclusiveMinimum"))
    hi = node.get("maximum", node.get("exclusiveMaximum"))
    if lo is None and hi is None:
        return None
    lo_s = "" if lo is None else (f"> {lo}" if "exclusiveMinimum" in node else f">= {lo}")
    hi_s = "" if hi is None else (f"< {hi}" if "exclusiveMaximum" in node else f"<= {hi}")
    return " and ".join(s for s in (lo_s, hi_s) if s)


def spec_errors(exc: ValidationError) -> list[ErrorDetails]:
    """pydantic's errors, a removed key's (``training.REMOVED_KEYS``) located at the key: its
    section's validator raised it, and the API and the CLI name the field from the location."""
    out = []
    for err in exc.errors(include_url=False):
        if err["type"] == "removed_field":
            err["loc"] = (*err["loc"], err["ctx"]["field"])
        out.append(err)
    return out


def _hashable(loc: tuple[Any, ...]) -> bool:
    return all(isinstance(p, (str, int)) for p in loc)


#: Longest message line: a validator's own text (which may hold what was sent) is cut to it.
MAX_MESSAGE = 400


def field_path(loc: tuple[Any, ...] | list[Any]) -> str:
    """``a.b.0.c``, each key cut to :data:`MAX_QUOTED` characters."""
    parts = [str(p) if len(str(p)) <= MAX_QUOTED else f"{str(p)[:MAX_QUOTED]}..." for p in loc]
    return ".".join(parts) or "(spec)"


def _cut(text: str) -> str:
    return text if len(text) <= MAX_MESSAGE else f"{text[:MAX_MESSAGE]}... (cut)"


def format_errors(exc: ValidationError, limit: int | None = MAX_ERRORS) -> list[str]:
    """One line per pydantic error (the first ``limit``): field path, the value sent (quoted up to
    :data:`MAX_QUOTED` characters), and what is allowed."""
    out = []
    for err in spec_errors(exc)[:limit]:
        loc = tuple(p for p in err["loc"])
        path = field_path(loc)
        kind = err["type"]
        value = err.get("input")
        known = _hashable(loc)
        if kind == "extra_forbidden":
            parent = (_field_schema(loc[:-1]) if known else None) if len(loc) > 1 else _spec_schema()
            allowed = sorted((parent or {}).get("properties", {}))
            out.append(f"{path}: unknown field; allowed fields here: {', '.join(allowed)}")
            continue
        node = _field_schema(loc) if loc and known else None
        rng = _range_text(node) if node else None
        if kind in {"greater_than", "greater_than_equal", "less_than", "less_than_equal"} and rng:
            out.append(f"{path}: {quote(value)} is out of range; allowed: {rng}")
        elif kind == "literal_error":
            out.append(_cut(f"{path}: {quote(value)} is not allowed; {err['msg'].lower()}"))
        elif kind == "removed_field":
            out.append(_cut(f"{path}: {err['msg']}"))
        elif kind == "value_error" or kind == "assertion_error":
            msg = err["msg"].removeprefix("Value error, ")
            out.append(_cut(f"{path}: {msg}"))
        elif kind == "missing":
            out.append(f"{path}: required")
        else:
            extra = f" (allowed: {rng})" if rng else ""
            out.append(_cut(f"{path}: {err['msg']}; got {quote(value)}{extra}"))
    return out


def spec_error(exc: ValidationError) -> SpecError:
    """The :class:`SpecError` of a failed validation: its first :data:`MAX_ERRORS` problems, the
    rest counted."""
    errors = spec_errors(exc)
    return SpecError(format_errors(exc), errors[:MAX_ERRORS], omitted=max(0, len(errors) - MAX_ERRORS))


def parse_spec(data: dict[str, Any] | str | bytes) -> JobSpec:
    """Validate a spec given as a dict or JSON text; raise :class:`SpecError` with readable messages."""
    try:
        if not isinstance(data, (str, bytes)):
            try:
                data = json.dumps(data, allow_nan=False)
            except ValueError:
                raise SpecError(["(spec): NaN and infinite numbers are not allowed"]) from None
            except TypeError as exc:
                raise SpecError([f"(spec): not a JSON document: {exc}"]) from None
        # Strict: "3" is not the integer 3 and true is not 1 (JSON numbers are still floats).
        return JobSpec.model_validate_json(data, strict=True)
    except ValidationError as exc:
        raise spec_error(exc) from None
