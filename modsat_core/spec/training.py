"""The `training` section of a :class:`~modsat_core.spec.jobspec.JobSpec`: TD3's settings, the budget,
and the schedules of exploration and of the design's learning (its own module, as the other
sections are in :mod:`modsat_core.spec.sections`)."""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from modsat_core.spec.sections import _Section

#: Keys removed from this section, each with the value that made it a no-op. A saved run's
#: spec.json lists every key of its day, so one that holds the no-op value still loads (the key
#: is dropped); any other value is refused by name (docs/lab/2026-12-05-unused-knobs-removed.md).
REMOVED_KEYS: dict[str, bool | int | None] = {
    "exploration_noise_decay_steps": None,
    "exploration_noise_min": None,
    "lr_final_fraction": None,
    "hold_cone_start_deg": None,
    "hold_cone_steps": None,
    "n_step": 1,
    "critic_layer_norm": False,
    "policy_noise_final": None,
}
REMOVED_KEYS_DOC = "docs/lab/2026-12-05-unused-knobs-removed.md"


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
    design_exploration_after_release: bool = Field(
        False,
        description=(
            "If true, designs are explored (cell swaps and action noise in the design phase) only once "
            "the actor's design layers learn (`design_learning_starts`, `design_learning_after_success`): "
            "until then every flight is on the policy's own design, so the controller learns to fly one "
            "satellite before it meets others. false = explored from the start."
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
            "seen (e67: once released, the design went from 27 modules to 1 in 5k steps). 0 = off (the paper)."
        ),
    )
    odd_control: bool = Field(
        False,
        description=(
            "Make the control output odd in the attitude error and rates: torque = tanh((g(x) - "
            "g(Px)) / 2), where P is the physical mirror of the state (the inverse error, the opposite "
            "rate) and keeps everything else (wheel momentum, design, counts). A pointed, still "
            "satellite then gets exactly zero torque whatever the weights, so a hold does not have "
            "to cancel a learned bias to a fraction of a percent of full scale. Design outputs are "
            "unchanged. false = the paper's actor."
        ),
    )
    observe_last_command: bool = Field(
        False,
        description=(
            "The actor and the critics also observe the last command: the action commanded at the previous "
            "control step (each wheel unit's own, and the mean over the units; zero at a flight's first step). "
            "With one control step of actuation delay the torque acting now is that command, so only with it "
            "is the plant Markov again. Whatever flies the policy feeds it its own previous command (the "
            "evaluation, the flight conditions, `modsat verify`); the exported controller takes it as a "
            "fourth input, `tau_last_B` (docs/export.md). On in the TD3 presets; false = the paper's "
            "observation (and every spec written before it)."
        ),
    )
    randomise_after_success: float | None = Field(
        None,
        gt=0.0,
        le=1.0,
        description=(
            "TD3 only (the first-order learner randomises from its first flight). A curriculum for "
            "`randomise`: training flights are nominal until an evaluation on the learning "
            "curve (`eval_episodes` nominal slews, the deterministic policy) lands at least this share of its "
            "slews; every flight that starts after it draws its flight conditions from `randomise`, to the "
            "end of the run. Read from the curve, so a resumed run keeps the switch. Once it has happened, the "
            "final evaluation chooses among the snapshots evaluated after it (docs/robustness.md). No effect "
            "without `randomise`. null = randomised from the first flight."
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
    select_top_k: int = Field(
        1,
        ge=1,
        le=20,
        description=(
            "The final evaluation flies the curve's best snapshot (success, then return) or, above 1, "
            "the best of the curve's k best on validation slews of their own seed, as many as "
            '`evaluation.episodes` (docs/learning.md, "Outputs of a run"). 1 = the curve\'s best.'
        ),
    )
    checkpoint_every_steps: int = Field(50_000, ge=1, le=1_000_000_000)
    device: Literal["auto", "cpu", "cuda"] = Field("auto", description="`auto` uses a GPU where torch sees one.")

    @model_validator(mode="before")
    @classmethod
    def _drop_removed_keys(cls, data: Any) -> Any:
        if not isinstance(data, dict) or not REMOVED_KEYS.keys() & data.keys():
            return data
        for key, noop in REMOVED_KEYS.items():
            value = data.get(key, noop)
            if type(value) is not type(noop) or value != noop:
                # Located at the key by jobspec.spec_errors (a section's validator is located at the section).
                raise PydanticCustomError(
                    "removed_field",
                    "removed from modsat (it was {value} here); only its no-op value {noop} is accepted, "
                    "drop the key or set it to that (see {doc})",
                    {"field": key, "value": json.dumps(value), "noop": json.dumps(noop), "doc": REMOVED_KEYS_DOC},
                )
        return {k: v for k, v in data.items() if k not in REMOVED_KEYS}

    def _schedule(self, start: float, final: float | None, env_steps: int) -> float:
        if final is None:
            return start
        span = max(self.total_env_steps - self.learning_starts, 1)
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
        return self._schedule(self.exploration_noise, self.exploration_noise_final, env_steps)

    def design_exploration_at(self, env_steps: int) -> float:
        """The design exploration probability after ``env_steps`` steps."""
        return self._schedule(self.design_exploration, self.design_exploration_final, env_steps)
