"""The `diffsim` section of a :class:`~modsat_core.spec.jobspec.JobSpec`: the first-order learner's
settings (docs/diffsim.md). The budget, the curve and the checkpoints stay in `training`
(`total_env_steps`, `eval_every_steps`, `eval_episodes`, `checkpoint_every_steps`, `device`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from modsat_core.spec.sections import _Section


class Diffsim(_Section):
    """Backpropagation of a smooth mission cost through the batched simulator (`diffsim-control`)."""

    base: Literal["pd", "none"] = Field(
        "pd",
        description=(
            "`pd`: the torque is the design's PD law (the baseline's) plus the network's correction, "
            "which starts near zero, so training starts from PD's slews and makes them faster. `none`: "
            "the network alone (learned from scratch; its slews settle later than PD's, docs/diffsim.md)."
        ),
    )
    design_pool: int = Field(
        0,
        ge=0,
        le=100_000,
        description=(
            "0: the controller flies the run's design (`design.fixed_design`) only. Above 0: a "
            "design-conditioned controller, its inputs extended by the design's (torque-to-inertia "
            "ratio per axis, products of inertia); each training slew flies the run's design or one of "
            "this many random valid designs of the design space (drawn once, cells empty, structure or "
            "actuator with equal chance), so that it flies a design it has not seen."
        ),
    )
    batch_size: int = Field(256, ge=1, le=16384, description="Training slews flown in parallel.")
    window_steps: int = Field(
        32,
        ge=1,
        le=500,
        description=(
            "Control steps per gradient window: the cost of this many steps is backpropagated, then the "
            "state is detached and the next window starts where this one ended."
        ),
    )
    episode_steps: int = Field(
        200,
        ge=1,
        le=100_000,
        description=(
            "Control steps of a training slew before a new one is drawn (at a window's end). The first "
            "slews are of staggered length, so that every window mixes slewing and holding."
        ),
    )
    substeps: int | None = Field(
        3,
        ge=1,
        le=1000,
        description=(
            "RK4 steps per control step in training (the control interval is kept: the physics step is "
            "`mission.control_dt_s / substeps`). null = the mission's own `frame_skip`. Evaluation always "
            "flies the mission's physics."
        ),
    )
    compiled: bool = Field(
        False,
        description=(
            "Fuse the RK4 step with torch.compile (one kernel per step, forward and backward) in the "
            "training simulator and the design scoring flights; each new shape compiles first (14-18 s "
            "measured on an AMD EPYC core). Measured on diffsim-5x5x5: training 1.54x faster, the same "
            "outcome (docs/diffsim.md, 'Compiled physics'); off by default, since the numbers agree with "
            "the eager step to rounding only. Validation and evaluation fly the eager simulator."
        ),
    )
    hidden_sizes: list[Annotated[int, Field(ge=4, le=1024)]] = Field(
        default_factory=lambda: [64, 64], min_length=1, max_length=4, description="tanh layers of the controller."
    )
    lr: float = Field(2e-3, gt=0.0, le=1.0, description="Adam learning rate at the start.")
    lr_final: float = Field(1e-4, gt=0.0, le=1.0, description="Learning rate at the end (cosine schedule).")
    grad_clip: float = Field(1.0, gt=0.0, le=1e6, description="Gradient-norm clip of each update.")
    rate_weight: float = Field(
        0.3, ge=0.0, le=100.0, description="Cost per rad/s of body rate, per step (the error costs 1 per rad)."
    )
    angle_log_weight: float = Field(
        0.1,
        ge=0.0,
        le=100.0,
        description="Weight of log(1 + angle / angle_log_scale_rad): the pull into the tolerance cone.",
    )
    angle_log_scale_rad: float = Field(0.002, gt=0.0, le=1.0, description="Scale of the log term of the angle.")
    rate_log_weight: float = Field(
        0.02, ge=0.0, le=100.0, description="Weight of log(1 + rate / rate_log_scale_rad_s): the pull to rest."
    )
    rate_log_scale_rad_s: float = Field(0.01, gt=0.0, le=10.0, description="Scale of the log term of the rate.")
    rate_barrier_fraction: float = Field(
        0.84,
        gt=0.0,
        le=1.0,
        description="The rate barrier starts at this fraction of `mission.rate_limit_rad_s`.",
    )
    barrier_weight: float = Field(
        1000.0, ge=0.0, le=1e9, description="Cost per (rad/s)^2 of rate over the barrier, per step."
    )
    terminal_weight: float = Field(
        8.0,
        ge=0.0,
        le=1000.0,
        description="The window's last step counts this many extra times (a stand-in for the cost after it).",
    )

    design_batch: int = Field(
        32,
        ge=2,
        le=4096,
        description="`diffsim-codesign`: designs drawn from the design distribution at each design update.",
    )
    design_slews: int = Field(
        8, ge=1, le=1000, description="`diffsim-codesign`: slews each drawn design flies for its objective."
    )
    design_every: int = Field(
        4, ge=1, le=10_000, description="`diffsim-codesign`: controller updates between design updates."
    )
    design_gradient: Literal["score-function", "relaxed"] = Field(
        "score-function",
        description=(
            "`diffsim-codesign`'s gradient for the design logits. `score-function`: REINFORCE on the "
            "drawn designs' objectives. `relaxed`: backpropagated through a relaxed grid (each cell's "
            "mass and wheel torque scaled by its probabilities) flown `design_slews` slews by the "
            "controller, its soft time out of tolerance plus the expected prices (docs/diffsim.md "
            "compares them)."
        ),
    )
    design_empty_prior: float | None = Field(
        None,
        gt=0.0,
        lt=1.0,
        description=(
            "`diffsim-codesign`: the probability with which the design distribution starts each free cell "
            "empty (the other types share the rest equally); null: every type equally likely. On a big grid "
            "a uniform start draws satellites of hundreds of modules; a sparse start draws small ones."
        ),
    )
    front_search_designs: int = Field(
        0,
        ge=0,
        le=100_000,
        description=(
            "`diffsim-codesign` with `objective.trade_off_prices_s_per_kg`: after training, how many designs "
            "the local search flies (the candidates, then neighbours of the non-dominated ones: one free cell "
            "changed, or two swapped), each on `design_slews` slews of the training physics; the non-dominated "
            "ones join the candidates for the validation slews. 0: no search."
        ),
    )
    design_lr: float = Field(
        0.1, gt=0.0, le=10.0, description="`diffsim-codesign`: Adam learning rate of the per-cell type logits."
    )

    @model_validator(mode="after")
    def _check(self) -> Diffsim:
        if self.lr_final > self.lr:
            raise ValueError(f"lr_final ({self.lr_final}) must not exceed lr ({self.lr})")
        return self
