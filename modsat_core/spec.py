"""`JobSpec`: the one typed description of a modsat run.

The API, the worker, the CLI and the web form all read and write this model. Every
number is bounded, unknown keys are rejected (``extra="forbid"``), and
:func:`parse_spec` turns pydantic's errors into messages that name the field, the value
and the allowed range.

Units are SI and are part of the field names where they matter (``_deg``, ``_Nm``...).
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator
from pydantic_core import ErrorDetails

from .spec_sections import GA, DesignSpace, Evaluation, Mission, ModuleCatalog, RewardSpec, _Section

__all__ = [
    "GA",
    "DesignSpace",
    "Evaluation",
    "JobSpec",
    "Mission",
    "ModuleCatalog",
    "RewardSpec",
    "SpecError",
    "Training",
    "UnrunnableSpec",
    "format_errors",
    "parse_spec",
]

SPEC_VERSION: Literal[1] = 1


class Training(_Section):
    """TD3 hyper-parameters (paper table) and the run's budget."""

    total_env_steps: int = Field(200_000, ge=1, le=1_000_000_000, description="Budget in control steps.")
    num_envs: int = Field(16, ge=1, le=8192, description="Episodes simulated in parallel.")
    network: Literal["per-module", "set"] = Field(
        "per-module",
        description=(
            "`per-module`: the paper's network, its trunk run on every cell, per-cell twin critics "
            "averaged. `set`: a small per-cell encoder, masked pooling over the satellite's cells, the "
            "wide layers once per satellite, per-cell design and control heads (docs/learning.md)."
        ),
    )
    hidden_sizes: list[Annotated[int, Field(ge=4, le=2048)]] = Field(
        default_factory=lambda: [400, 300],
        min_length=1,
        max_length=4,
        description="Wide layers: the shared trunk (`per-module`) or the per-satellite layers (`set`).",
    )
    actor_lr: float = Field(3e-4, gt=0.0, le=1.0, description="Adam learning rate of the shared actor.")
    critic_lr: float = Field(3e-3, gt=0.0, le=1.0, description="Adam learning rate of the twin critics.")
    batch_size: int = Field(512, ge=1, le=65536, description="Transitions per gradient update.")
    buffer_size: int = Field(500_000, ge=100, le=10_000_000, description="Replay buffer capacity (transitions).")
    gamma: float = Field(0.99, ge=0.0, lt=1.0, description="Discount factor.")
    tau: float = Field(0.005, gt=0.0, le=1.0, description="Polyak factor (the paper's 0.995 written the other way).")
    exploration_noise: float = Field(0.2, ge=0.0, le=2.0, description="Std of the Gaussian action noise.")
    exploration_noise_final: float | None = Field(
        None,
        ge=0.0,
        le=2.0,
        description=(
            "If set, the exploration noise falls linearly from `exploration_noise` (when learning "
            "starts) to this value (at the end of the budget). null = constant noise (the paper)."
        ),
    )
    exploration_noise_decay_steps: int | None = Field(
        None,
        ge=1,
        le=1_000_000_000,
        description=(
            "Env steps (counted from `learning_starts`) over which the exploration noise falls to "
            "`exploration_noise_final`, then stays there. null = over the whole budget."
        ),
    )
    design_exploration: float = Field(
        0.1, ge=0.0, le=1.0, description="Probability that a cell's design action is replaced by a random type."
    )
    design_exploration_episodes: float = Field(
        1.0,
        ge=0.0,
        le=1.0,
        description=(
            "Share of episodes whose design phase is explored (random cell swaps and action noise), "
            "drawn per episode. The others grow the policy's own design without noise, so that most "
            "flights train the controller on the design being learned. 1 = every episode (the paper)."
        ),
    )
    design_exploration_final: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description=(
            "If set, `design_exploration` falls linearly to this value over the budget, as the "
            "exploration noise does: designs drawn widely while the controller learns to fly many "
            "of them, then narrowed. null = constant."
        ),
    )
    design_learning_starts: int = Field(
        0,
        ge=0,
        le=1_000_000_000,
        description=(
            "Env steps before the actor's design layers learn: until then the policy grows the design "
            "it starts from (the full cube around the seed actuator, with the set network) and the "
            "controller learns to fly it and the explored designs near it. The design critic learns "
            "from the start. 0 = from the start (the paper)."
        ),
    )
    design_learning_after_success: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description=(
            "If set, the actor's design layers are also held until an evaluation on the learning "
            "curve lands at least this share of its slews on the design being flown (and "
            "`design_learning_starts` has passed): the design moves only once the controller can fly "
            "the one it has. Once reached, the design learns to the end of the run. null = no gate."
        ),
    )
    design_bc: float = Field(
        0.0,
        ge=0.0,
        le=100.0,
        description=(
            "Weight of a behaviour-cloning term on the actor's design actions, as TD3+BC (Fujimoto "
            "and Gu 2021): the squared distance between the design head's outputs and the design "
            "actions in the replay, times the mean |Q| of the batch's design rows, is added to the "
            "design rows' loss. It keeps the design head near the designs that have been flown, "
            "where the critic has data, instead of following the critic to designs it has never "
            "seen (e67: released at once, the design went from 27 modules to 1). 0 = off (the paper)."
        ),
    )
    n_step: int = Field(
        1,
        ge=1,
        le=20,
        description=(
            "Steps of reward summed before bootstrapping in the critic's target (n-step return, "
            "stopping at the episode's end). 1 = the paper's one-step TD3."
        ),
    )
    policy_noise: float = Field(0.2, ge=0.0, le=2.0, description="Target policy smoothing std.")
    noise_clip: float = Field(0.5, ge=0.0, le=2.0, description="Clip of the target smoothing noise.")
    action_l2: float = Field(
        0.0,
        ge=0.0,
        le=1000.0,
        description=(
            "Weight of the flight actions' squared torque commands (in [-1, 1], summed over the "
            "actuators) added to the actor's loss, as HER's `action_l2` (Andrychowicz et al. 2017): it "
            "keeps the policy out of tanh saturation so that it learns the small torques of a hold. "
            "0 = off (the paper)."
        ),
    )
    policy_delay: int = Field(2, ge=1, le=100, description="Critic updates per actor/target update.")
    train_frequency: int = Field(2, ge=1, le=1000, description="Env steps between gradient updates.")
    learning_starts: int = Field(10_000, ge=0, le=10_000_000)
    eval_every_steps: int = Field(20_000, ge=1, le=1_000_000_000)
    eval_episodes: int = Field(16, ge=1, le=1000, description="Episodes of each evaluation on the curve.")
    checkpoint_every_steps: int = Field(50_000, ge=1, le=1_000_000_000)
    device: Literal["auto", "cpu", "cuda"] = Field("auto", description="`auto` uses a GPU where torch sees one.")

    def _schedule(self, start: float, final: float | None, env_steps: int, span: int | None = None) -> float:
        if final is None:
            return start
        span = max(self.total_env_steps - self.learning_starts, 1) if span is None else span
        frac = min(max((env_steps - self.learning_starts) / span, 0.0), 1.0)
        return start + frac * (final - start)

    @field_validator("buffer_size")
    @classmethod
    def _check_batch(cls, v: int, info: Any) -> int:
        batch = info.data.get("batch_size")
        if batch is not None and batch > v:
            raise ValueError(
                f"buffer_size ({v}) must be at least batch_size ({batch}): an update samples "
                f"batch_size transitions from the buffer"
            )
        return v

    def noise_at(self, env_steps: int) -> float:
        """The exploration noise std after ``env_steps`` steps (see `exploration_noise_final`)."""
        return self._schedule(
            self.exploration_noise, self.exploration_noise_final, env_steps, self.exploration_noise_decay_steps
        )

    def design_exploration_at(self, env_steps: int) -> float:
        """The design exploration probability after ``env_steps`` steps."""
        return self._schedule(self.design_exploration, self.design_exploration_final, env_steps)


class JobSpec(_Section):
    """A whole run: what to optimise, on which mission, with which budget."""

    version: Literal[1] = SPEC_VERSION
    name: str | None = Field(None, max_length=200, description="A label for people; not used by the run.")
    algorithm: Literal["td3-codesign", "ga", "td3-control"] = Field(
        "td3-codesign",
        description="`td3-codesign`: NCA design + control by TD3 (paper). `ga`: GA over designs with TD3 "
        "inner loops. `td3-control`: TD3 control of `design.fixed_design`.",
    )
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seeds networks, exploration and training slews.")
    design: DesignSpace = Field(default_factory=DesignSpace)
    modules: ModuleCatalog = Field(default_factory=ModuleCatalog)
    mission: Mission = Field(default_factory=Mission)
    training: Training = Field(default_factory=Training)
    ga: GA = Field(default_factory=GA)
    evaluation: Evaluation = Field(default_factory=Evaluation)

    @model_validator(mode="after")
    def _check_consistency(self) -> JobSpec:
        if self.algorithm == "td3-control" and self.design.fixed_design is None:
            raise ValueError("algorithm 'td3-control' needs design.fixed_design")
        if self.modules.momentum_capacity_Nms is not None and self.modules.actuator_model != "reaction-wheel":
            raise ValueError("modules.momentum_capacity_Nms is only meaningful with actuator_model 'reaction-wheel'")
        return self


class UnrunnableSpec(ValueError):
    """A valid spec that cannot run where it was sent (e.g. ``device: cuda`` without a GPU).
    Retrying cannot help: a worker fails the job at once."""


class SpecError(ValueError):
    """A spec that failed validation; ``messages`` has one readable line per problem."""

    def __init__(self, messages: list[str], errors: list[ErrorDetails] | None = None):
        self.messages = messages
        self.errors = errors or []
        super().__init__("invalid spec:\n  " + "\n  ".join(messages))


def _field_schema(loc: tuple[Any, ...]) -> dict[str, Any] | None:
    """The JSON-schema node of the field at ``loc`` (resolving $refs), or None."""
    schema = JobSpec.model_json_schema()
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


def format_errors(exc: ValidationError) -> list[str]:
    """One line per pydantic error: field path, offending value, and what is allowed."""
    out = []
    for err in exc.errors():
        loc = tuple(p for p in err["loc"])
        path = ".".join(str(p) for p in loc) or "(spec)"
        kind = err["type"]
        value = err.get("input")
        if kind == "extra_forbidden":
            parent = _field_schema(loc[:-1]) if len(loc) > 1 else JobSpec.model_json_schema()
            allowed = sorted((parent or {}).get("properties", {}))
            out.append(f"{path}: unknown field; allowed fields here: {', '.join(allowed)}")
            continue
        node = _field_schema(loc) if loc else None
        rng = _range_text(node) if node else None
        if kind in {"greater_than", "greater_than_equal", "less_than", "less_than_equal"} and rng:
            out.append(f"{path}: {value!r} is out of range; allowed: {rng}")
        elif kind == "literal_error":
            out.append(f"{path}: {value!r} is not allowed; {err['msg'].lower()}")
        elif kind == "value_error" or kind == "assertion_error":
            msg = err["msg"].removeprefix("Value error, ")
            out.append(f"{path}: {msg}")
        else:
            extra = f" (allowed: {rng})" if rng else ""
            shown = repr(value) if not isinstance(value, dict) else "{...}"
            out.append(f"{path}: {err['msg']}; got {shown}{extra}")
    return out


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
        raise SpecError(format_errors(exc), exc.errors(include_url=False)) from None
