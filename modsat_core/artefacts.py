"""The records a run produces, typed and torch-free (pydantic, numpy and the stdlib only).

One owner for the formats of

* the progress record (the dict ``on_progress`` gets; a row of ``/api/jobs/{id}/metrics``)
  and its learning-curve point (``eval``; a point of ``curve.json``);
* ``design.json``, ``evaluation.json``, ``trajectories.json`` and ``curve.json``;
* the short evaluation summary of a finished run (the API's ``evaluation`` of a job).

The writers (modsat_core.evaluation.run_files, td3_run, ga), the job store, the API models, the viewer
(web.viewer.run) and the tests build and read them through these models (docs/learning.md,
"Outputs of a run", lists the files). A record keeps the keys it was given, in their order,
and only those: an optional key a writer left out is absent from the file and from the API,
not ``null``; unknown keys (e.g. success at a mission tolerance other than 0.25 and 1 deg, or a custom
runner's figures) are kept, so that files of older runs still read. A file that does not fit
is refused with an :class:`ArtefactError` naming the file and the field.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, ClassVar, TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, model_serializer, model_validator

from modsat_core.grid import ACTUATOR, EMPTY, as_grid, is_valid

#: ``types`` of design.json: what the grid's numbers mean.
CELL_TYPES = {"0": "empty", "1": "structure", "2": "actuator"}

R = TypeVar("R", bound="Record")


class ArtefactError(ValueError):
    """A file or record that is not in its format (the message names the file and the field)."""


class Record(BaseModel):
    """A JSON record: the keys it was given (known ones typed), unknown keys kept."""

    model_config = ConfigDict(extra="allow", populate_by_name=True)
    FILE: ClassVar[str] = "record"  # the name errors are reported under

    _order: tuple[str, ...] = PrivateAttr(default=())  # the keys as given: written back in this order

    @model_validator(mode="wrap")
    @classmethod
    def _remember_order(cls, data: Any, handler: Any) -> Any:
        rec = handler(data)
        if isinstance(data, Mapping) and isinstance(rec, Record):
            rec._order = tuple(str(k) for k in data)
        return rec

    @model_serializer(mode="wrap")
    def _given_keys_only(self, handler):  # no return annotation: the JSON schema stays the model's
        fields = type(self).model_fields
        # The file's keys (aliases), whatever ``by_alias`` a caller asked for.
        out = {(fields[k].alias or k) if k in fields else k: v for k, v in handler(self).items()}
        given = {fields[n].alias or n if n in fields else n for n in self.model_fields_set}
        given |= set(self.__pydantic_extra__ or ())
        order = [fields[k].alias or k if k in fields else k for k in self._order]
        return {k: out[k] for k in dict.fromkeys([*order, *out]) if k in out and k in given}

    @classmethod
    def parse(cls: type[R], data: bytes | str | Mapping[str, Any] | None, what: str | None = None) -> R:
        """From JSON text (bytes or str) or decoded JSON; :class:`ArtefactError` if it does not fit."""
        what = what or cls.FILE
        try:
            obj = json.loads(data) if isinstance(data, (bytes, bytearray, str)) else data
        except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
            raise ArtefactError(f"{what} is not JSON: {exc}") from None
        try:
            return cls.model_validate(obj)
        except ValidationError as exc:
            problems = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'the record'}: {e['msg']}" for e in exc.errors()[:5]
            )
            raise ArtefactError(f"{what} is not a modsat {cls.__name__}: {problems}") from None

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (NaN and infinities become null)."""
        return self.model_dump(mode="json", by_alias=True)

    def to_json(self, indent: int | None = None) -> bytes:
        return json.dumps(self.to_dict(), indent=indent).encode()


class _Success(Record):
    """Success rates at the report tolerances, 0.25 and 1 deg (reports.REPORT_TOLERANCES_DEG)."""

    success_rate_at_0_25_deg: float | None = Field(None, alias="success_rate_at_0.25_deg")
    success_rate_at_1_deg: float | None = None

    def success_at(self, tolerance_deg: float) -> float | None:
        """Success rate at ``tolerance_deg`` (a report tolerance, or one kept as an unknown key)."""
        value = self.to_dict().get(f"success_rate_at_{tolerance_deg:g}_deg")
        return None if value is None else float(value)


class CurvePoint(_Success):
    """A learning-curve evaluation (reports.curve_point; the GA's best design so far)."""

    FILE: ClassVar[str] = "learning-curve point"
    env_steps: int
    mean_return: float | None
    success_rate: float | None = Field(description="Success at the mission's tolerance.")
    updates: int | None = None
    valid: bool | None = None
    modules: int | None = None
    actuators: int | None = None
    median_final_error_deg: float | None = None
    median_slew_time_ratio: float | None = None
    design_return: float | None = Field(None, description="GA: the mean return of the design just evaluated.")
    generation: int | None = Field(None, description="GA: the generation of that design.")
    loss: float | None = Field(None, description="diffsim: the mean cost of the last update's window.")
    grad_norm: float | None = Field(None, description="diffsim: the last update's gradient norm, before clipping.")


class ProgressRecord(Record):
    """What a training reports through ``on_progress`` (docs/train-interface.md)."""

    FILE: ClassVar[str] = "progress record"
    env_steps: int = 0
    total_env_steps: int | None = None
    updates: int | None = None
    phase: str | None = Field(None, description="training | evaluating, or 'ga generation G, design D'.")
    stage: str | None = Field(None, description="evaluating: what the final evaluation flies now.")
    eval: CurvePoint | None = Field(None, description="A learning-curve point, when one was just evaluated.")
    train_episodes: int | None = Field(None, description="Training episodes finished since the last record.")
    train_mean_return: float | None = None
    train_valid_rate: float | None = None
    train_success_rate: float | None = None
    critic_loss: float | None = None
    loss: float | None = Field(None, description="diffsim: the mean cost of the last update's window.")
    grad_norm: float | None = Field(None, description="diffsim: the last update's gradient norm, before clipping.")
    actor_loss: float | None = None
    q: float | None = None
    elapsed_s: float | None = Field(None, description="Added by the worker: run time of the job's attempts so far.")


class _DesignFigures(Record):
    grid_size: int
    valid: bool = Field(description="Face-connected with at least one actuator.")
    modules: int
    actuators: int
    types: dict[str, str] = Field(default_factory=lambda: dict(CELL_TYPES))
    mass_kg: float | None = None
    com_grid_m: list[float] | None = Field(None, description="Centre of mass in the grid frame, m.")
    inertia_kgm2: list[list[float]] | None = Field(None, description="Inertia tensor about the centre of mass.")
    principal_inertia_kgm2: list[float] | None = None


class DesignFigures(_DesignFigures):
    """``design.json`` less its grid: the design in a run's evaluation summary."""


class DesignReport(_DesignFigures):
    """``design.json``: the grid (0 empty, 1 structure, 2 actuator) and its figures."""

    FILE: ClassVar[str] = "design.json"
    grid: list[list[list[int]]]

    @model_validator(mode="after")
    def _figures_match_the_grid(self) -> DesignReport:
        g = as_grid(self.grid)
        found = {"grid_size": g.shape[0], "modules": int((g != EMPTY).sum()), "actuators": int((g >= ACTUATOR).sum())}
        wrong = [f"{k} is {getattr(self, k)}, the grid has {v}" for k, v in found.items() if getattr(self, k) != v]
        if wrong:
            raise ValueError("; ".join(wrong))
        return self

    @classmethod
    def of(cls, grid: Any, **figures: Any) -> DesignReport:
        """The report of ``grid`` (mass figures, if any, in ``figures``)."""
        g = np.asarray(grid)
        return cls(
            grid=g.tolist(),
            grid_size=int(g.shape[0]),
            valid=bool(is_valid(g)),
            modules=int((g != EMPTY).sum()),
            actuators=int((g >= ACTUATOR).sum()),
            types=dict(CELL_TYPES),
            **figures,
        )

    @property
    def array(self) -> np.ndarray:
        return np.asarray(self.grid, dtype=np.int64)

    def figures(self) -> DesignFigures:
        return DesignFigures.model_validate({k: v for k, v in self.to_dict().items() if k != "grid"})


class EpisodeMetrics(Record):
    """One evaluation slew's figures (slew.episode_metrics; NaN written as null)."""

    success: bool | None = None
    safety_violation: bool | None = None
    final_error_deg: float | None = None
    final_rate_rad_s: float | None = None
    settling_time_s: float | None = None
    slew_time_ratio: float | None = Field(None, description="Settling time / the eigenaxis time-optimal bound.")
    eigenaxis_bound_s: float | None = None
    slew_angle_deg: float | None = None
    effort_Nms: float | None = None
    peak_rate_rad_s: float | None = None
    return_: float | None = Field(None, alias="return")
    duration_s: float | None = None
    rate_tolerance_rad_s: float | None = None


class EvaluationSummary(_Success):
    """A Monte-Carlo evaluation's figures (evaluate.MonteCarloResult.summary)."""

    episodes: int
    success_rate: float = Field(description="Success at the mission's tolerance.")
    mean_return: float | None
    std_return: float | None = None
    safety_violations: int | None = None
    median_final_error_deg: float | None = None
    median_final_rate_rad_s: float | None = None
    median_settling_time_s: float | None = None
    median_slew_time_ratio: float | None = None
    median_effort_Nms: float | None = None
    max_peak_rate_rad_s: float | None = None


class ControllerEvaluation(Record):
    summary: EvaluationSummary
    episodes: list[EpisodeMetrics] = Field(default_factory=list)


class ConditionEvaluation(Record):
    """One flight condition of the evaluation (docs/robustness.md): the policy and PD on the same
    slews under it."""

    name: str
    changes: dict[str, float | int | None] = Field(description="What departs from the nominal flight.")
    policy: EvaluationSummary
    pd_baseline: EvaluationSummary


#: A flight condition is *failed* when PD lands at least this share of its slews and the policy lands
#: less than this share of what PD lands (docs/robustness.md, "Failures are flagged").
FAILURE_SHARE = 0.9


class FlightFailure(Record):
    """A flight condition the policy fails where PD lands (:data:`FAILURE_SHARE`)."""

    name: str
    policy_success: float
    pd_success: float


def flight_failures(conditions: list[ConditionEvaluation]) -> list[FlightFailure]:
    """The conditions of ``conditions`` where PD lands and the policy does not (:data:`FAILURE_SHARE`)."""
    out = []
    for c in conditions:
        pol, pd = c.policy.success_rate, c.pd_baseline.success_rate
        if pd >= FAILURE_SHARE and pol < FAILURE_SHARE * pd:
            out.append(FlightFailure(name=c.name, policy_success=pol, pd_success=pd))
    return out


class EvaluationReport(Record):
    """``evaluation.json``: the policy and the PD baseline on the same seeded slews, nominal and under
    each of ``evaluation.conditions``."""

    FILE: ClassVar[str] = "evaluation.json"
    episodes: int
    seed: int
    design_valid: bool
    policy: ControllerEvaluation
    pd_baseline: ControllerEvaluation | None = Field(description="null when the design is not a valid satellite.")
    conditions: list[ConditionEvaluation] = Field(
        default_factory=list, description="Empty for runs written before conditions were evaluated."
    )
    requirements: dict[str, Any] | None = Field(
        None,
        description=(
            "With the spec's `requirements`: whether the design and its controller meet them (`meets`), every "
            "requirement missed (`reasons`), the design's mass and power, and the share of slews that settle "
            "within the time, nominally and under each condition (docs/requirements.md)."
        ),
    )
    flight_failures: list[FlightFailure] = Field(
        default_factory=list,
        description=(
            "The conditions where PD lands at least 90 % of the slews and the policy less than 90 % of what PD "
            "lands: a controller not ready for flight under them (empty: none, or no conditions flown)."
        ),
    )


class Trajectory(Record):
    """Time histories of one evaluation slew (T samples; quaternions scalar first)."""

    t_s: list[float]
    q_BN: list[list[float]] | None = None
    omega_B: list[list[float]] | None = Field(None, description="rad/s")
    h_B: list[list[float]] | None = Field(None, description="Total wheel momentum in the body frame, N m s.")
    tau_c_B: list[list[float]] | None = Field(None, description="Control torque on the body, N m.")
    error_deg: list[float] | None = None
    q_TN: list[float] | None = None
    metrics: EpisodeMetrics | None = None

    @model_validator(mode="after")
    def _shapes(self) -> Trajectory:
        n = len(self.t_s)
        for key, width in (("q_BN", 4), ("omega_B", 3), ("h_B", 3), ("tau_c_B", 3), ("error_deg", None)):
            v = getattr(self, key)
            if v is None:
                continue
            if len(v) != n or (width is not None and any(len(row) != width for row in v)):
                shape = f"({n},)" if width is None else f"({n}, {width})"
                raise ValueError(f"{key} must be {shape} like t_s ({n} samples)")
        if self.q_TN is not None and len(self.q_TN) != 4:
            raise ValueError("q_TN must hold 4 numbers")
        return self


class Trajectories(Record):
    """``trajectories.json``: the first few evaluation slews of each controller."""

    FILE: ClassVar[str] = "trajectories.json"
    policy: list[Trajectory] = Field(default_factory=list)
    pd_baseline: list[Trajectory] = Field(default_factory=list)


class CurveFile(Record):
    """``curve.json``: the learning curve (a GA run adds ``designs`` and ``generations``)."""

    FILE: ClassVar[str] = "curve.json"
    algorithm: str
    points: list[CurvePoint]
    best_env_steps: int | None = Field(None, description="TD3: the point whose policy the final evaluation flies.")
    selection: list[dict[str, Any]] | None = Field(
        None,
        description=(
            "TD3 with `training.select_top_k` > 1: each candidate's figures on the validation slews. "
            "diffsim-codesign: each candidate design's objective there."
        ),
    )
    designs: list[dict[str, Any]] | None = Field(
        None,
        description=(
            "GA: every evaluated design, in order. diffsim-codesign: each design update (the "
            "distribution's mode, its draws' objective)."
        ),
    )
    generations: list[dict[str, Any]] | None = Field(None, description="GA: the survivor schedule.")
    initial_design: dict[str, Any] | None = Field(
        None,
        description=(
            "diffsim-codesign without a trade-off: the paper's initial design (the full cube, its centre a "
            "wheel unit, the payload as structure) flown by the controller at the end of training on the "
            "candidates' validation slews: `grid`, `objective_s`. Absent for a trade-off (its front is the "
            "comparison) and where a payload covers the cube's centre (no wheel unit)."
        ),
    )


class RunSummary(Record):
    """A finished run's short evaluation summary (``RunResult.summary``; a job's ``evaluation``)."""

    FILE: ClassVar[str] = "evaluation summary"
    policy: EvaluationSummary | None = None
    pd_baseline: EvaluationSummary | None = None
    design: DesignFigures | None = None
    designs_evaluated: int | None = Field(None, description="GA: designs evaluated.")
    conditions: list[ConditionEvaluation] = Field(
        default_factory=list, description="The policy and PD under each flight condition (docs/robustness.md)."
    )

    @property
    def flight_failures(self) -> list[FlightFailure]:
        """The conditions the policy fails where PD lands (:func:`flight_failures`)."""
        return flight_failures(self.conditions)


def conditions_table(
    nominal: tuple[EvaluationSummary | None, EvaluationSummary | None], conditions: list[ConditionEvaluation]
) -> list[list[str]]:
    """Rows of the robustness table (header first): per condition, success (the mission's), safety
    violations and median settling time of the policy and of PD, nominal first."""

    def cells(s: EvaluationSummary | None) -> list[str]:
        if s is None:
            return ["-", "-", "-"]
        rate, settle = s.success_rate, s.median_settling_time_s
        return [
            f"{100 * rate:.0f}%",
            "-" if s.safety_violations is None else str(s.safety_violations),
            "-" if settle is None else f"{settle:.2f}",
        ]

    rows = [["condition", "policy success", "viol", "settle s", "PD success", "viol", "settle s"]]
    rows.append(["nominal", *cells(nominal[0]), *cells(nominal[1])])
    rows += [[c.name, *cells(c.policy), *cells(c.pd_baseline)] for c in conditions]
    return rows
