"""What a spec will cost a machine, and the limits a service (or the CLI) puts on it.

Every field of a :class:`~modsat_core.spec.jobspec.JobSpec` is bounded on its own; combinations are
not: a 10^3 grid with a 500,000-transition replay buffer needs 9.4 GiB before the first step,
and 10,000 evaluation slews of a 10^3 grid fly in one batch of 10,000 x 1,000 cells. This
module estimates a spec's peak memory and its work (env steps to train, control steps to
evaluate) and says, naming the field to change, where a limit is exceeded. It imports no
torch, so the API process can check a submission cheaply.

The memory figure is an estimate, on the high side, of the largest allocations: the replay
buffer (exact: the compact replay row, :data:`REPLAY_STATE` and :data:`REPLAY_ROW`, which the
buffer itself is built from), one TD3 update's activations
(features of both states, every layer's output kept for the backward pass, actor, target
actor and four critic passes), the per-step features of the training envs, and the
Monte-Carlo evaluation's batch (the nominal slews, or the slews of every flight condition flown
at once, whichever is larger). docs/service.md ("Limits") lists the defaults.

The work figure (:func:`work`) is an estimate, on the high side, of a run's wall time on one CPU core:
the simulator's RK4 steps (a fixed cost per batched step plus a cost per satellite and wheel-unit slot),
the networks' floating-point work (per sample, from their shapes), a fixed cost per TD3 update and per
GA design, the evaluations, the co-design's design flights and the checkpoints. Its constants were
measured with ``modsat bench sim`` and ``modsat bench update`` on the 2-core development machines
(AMD EPYC / Intel Xeon, torch 2.13 CPU, one thread) and rounded towards the slow side. A run that
may use a GPU (``training.device`` `auto` or `cuda`) is credited :attr:`Limits.gpu_speedup`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from modsat_core.spec.jobspec import JobSpec, Training, is_diffsim

#: Per-cell features (``features.N_FEATURES``; a test checks they agree), and those the last command
#: adds with `training.observe_last_command` (``features.N_LAST_COMMAND``).
N_FEATURES = 53
N_LAST_COMMAND = 6
#: Per-cell encoder width of the set network (``networks.SET_CELL_WIDTH``; a test checks it).
SET_CELL_WIDTH = 32
#: Layer outputs kept per cell and wide layer in one TD3 update (forward and backward of the
#: actor, the target actor, twin critics and twin target critics, the actor loss's critic pass).
_UPDATE_PASSES = 10
#: Working copies of the per-cell features while stepping or evaluating (features, network
#: input, layer outputs).
_STEP_COPIES = 4
#: Bytes the graph of a first-order (`diffsim-control`) update keeps per training slew and RK4 step,
#: and per control step (the controller's layers, the cost): measured on a 3x3x3 design with 1 and 3
#: wheel units, B = 1024 and 2048, 16 steps of 5 substeps (1.4 and 0.9 KB), rounded up.
DIFFSIM_BYTES_PER_SUBSTEP = 1536
DIFFSIM_BYTES_PER_STEP = 2048
#: ... and per wheel unit and RK4 step (the units' momentum and its RK4 stages; an upper bound, as
#: the measurement above includes 1-3 units). A design pool can hold up to N^3 units a design.
DIFFSIM_BYTES_PER_UNIT_SUBSTEP = 160
#: `diffsim-codesign` with ``design_gradient`` `relaxed`: the relaxed flight keeps the graph of a
#: whole episode of ``design_slews`` slews in float64, each with a slot for every cell's wheel unit.
#: Per slew, control step and RK4 step it is bounded by twice a training window's bytes (float64);
#: besides, the graph keeps per control step what does not grow with the slews. Measured (peak RSS
#: growth of one relaxed objective and its backward pass, 500 steps of 5 substeps): 3x3x3, 16 and
#: 64 slews, 440 and 647 MiB; 5x5x5, 1.6 GiB with 64 slews; the bound below gives 2.2-4.5x that.
RELAXED_BYTES_PER_STEP = 2**20
#: What a run needs besides the estimate above: the interpreter, torch, the simulator.
BASE_BYTES = 600 * 2**20
GIB = 2**30


#: The compact replay row, one table for the buffer (``training.replay_layout.replay_fields`` makes
#: torch dtypes of the names) and for the memory estimate here: name, shape ("C" is the number
#: of cells, N^3), dtype. A state: the grid (a type per cell), the design step, q_BN, q_TN, the
#: body rate and each cell's wheel momentum; a row holds two states, "obs_" and "next_".
REPLAY_STATE: tuple[tuple[str, tuple[int | str, ...], str], ...] = (
    ("grid", ("C",), "uint8"),
    ("design_step", (), "int16"),
    ("q_BN", (4,), "float32"),
    ("q_TN", (4,), "float32"),
    ("omega_B", (3,), "float32"),
    ("h_cells", ("C", 3), "float16"),
)
#: The rest of a row: the action (three numbers per cell), the reward and whether it was terminal.
REPLAY_ROW: tuple[tuple[str, tuple[int | str, ...], str], ...] = (
    ("action", ("C", 3), "float16"),
    ("reward", (), "float32"),
    ("terminal", (), "bool"),
)
#: With `training.observe_last_command`: the observed state's last command (the action commanded one
#: control step before it, per cell). The next state's is the row's action (zero where the observed
#: state was designing: its flight starts with no command), so it is not stored twice.
REPLAY_LAST_COMMAND: tuple[str, tuple[int | str, ...], str] = ("obs_last_cmd", ("C", 3), "float16")
_ITEM_BYTES = {"uint8": 1, "bool": 1, "int16": 2, "float16": 2, "float32": 4}


def replay_layout(N: int, last_command: bool = False) -> dict[str, tuple[tuple[int, ...], str]]:
    """The fields of one replay transition on an N^3 grid: name -> (shape, dtype name); with
    ``last_command`` (`training.observe_last_command`) the observed state's last command too."""
    C = N**3

    def shape(dims: tuple[int | str, ...]) -> tuple[int, ...]:
        return tuple(C if d == "C" else int(d) for d in dims)

    fields = {f"{side}_{k}": (shape(dims), dt) for side in ("obs", "next") for k, dims, dt in REPLAY_STATE}
    fields.update({k: (shape(dims), dt) for k, dims, dt in REPLAY_ROW})
    if last_command:
        name, dims, dt = REPLAY_LAST_COMMAND
        fields[name] = (shape(dims), dt)
    return fields


def transition_bytes(N: int, last_command: bool = False) -> int:
    """Bytes of one replay transition on an N^3 grid (:func:`replay_layout`)."""
    return sum(math.prod(shape) * _ITEM_BYTES[dt] for shape, dt in replay_layout(N, last_command).values())


def replay_capacity(training: Training) -> int:
    """The transitions a TD3 run's replay buffer holds: ``buffer_size``, but no more than the run
    will ever store (its env steps, at least one batch)."""
    return min(training.buffer_size, max(training.total_env_steps, training.batch_size))


@dataclass(frozen=True)
class Estimate:
    replay_bytes: int
    update_bytes: int
    step_bytes: int
    evaluation_bytes: int
    train_env_steps: int
    evaluation_steps: int
    #: `diffsim-codesign`: the largest batch of designs flown at once (a design update's draws x
    #: slews, or the kept design's candidates on the validation slews).
    design_bytes: int = 0
    #: ... and the relaxed design gradient's flight with its graph (``design_gradient`` `relaxed`).
    relaxed_bytes: int = 0

    @property
    def memory_bytes(self) -> int:
        flights = max(self.step_bytes, self.evaluation_bytes, self.design_bytes, self.relaxed_bytes)
        return BASE_BYTES + self.replay_bytes + self.update_bytes + flights

    def as_dict(self) -> dict:
        return {
            "memory_bytes": self.memory_bytes,
            "replay_bytes": self.replay_bytes,
            "update_bytes": self.update_bytes,
            "step_bytes": self.step_bytes,
            "evaluation_bytes": self.evaluation_bytes,
            "design_bytes": self.design_bytes,
            "relaxed_bytes": self.relaxed_bytes,
            "train_env_steps": self.train_env_steps,
            "evaluation_steps": self.evaluation_steps,
        }


def estimate(spec: JobSpec) -> Estimate:
    """Peak memory and work of a run of ``spec`` (see the module docstring)."""
    t, m, e = spec.training, spec.mission, spec.evaluation
    N = spec.design.grid_size
    C = N**3
    F = N_FEATURES + (N_LAST_COMMAND if t.observe_last_command else 0)
    H = sum(t.hidden_sizes)
    per_cell_width = H if t.network == "per-module" else SET_CELL_WIDTH
    update = 4 * t.batch_size * (C * (2 * F + _UPDATE_PASSES * per_cell_width) + _UPDATE_PASSES * H)
    step = 4 * t.num_envs * C * (F + 3) * _STEP_COPIES
    # The final evaluation flies the nominal slews in one batch and every flight condition's in
    # another (episodes x conditions rows).
    conditions = len(e.conditions)
    evaluation = 4 * max(e.episodes * max(1, conditions), t.eval_episodes) * C * (F + 3) * _STEP_COPIES
    # Curve points (one every eval_every_steps, and one at the end), then the final Monte-Carlo
    # evaluation, nominal and under each condition, flown by the policy and by the PD baseline.
    curve_points = t.total_env_steps // t.eval_every_steps + 1
    evaluation_steps = m.episode_steps * (curve_points * t.eval_episodes + 2 * e.episodes * (1 + conditions))
    if is_diffsim(spec):  # no replay, no per-cell features: one window's graph
        d = spec.diffsim
        substeps = m.frame_skip if d.substeps is None else d.substeps
        fixed = spec.design.fixed_design
        codesign = spec.algorithm == "diffsim-codesign"  # its draws may hold a unit in every cell
        if d.design_pool or fixed is None or codesign:
            units = spec.design.grid_size**3
        else:
            units = sum(c == 2 for c in _cells(fixed))
        per_substep = DIFFSIM_BYTES_PER_SUBSTEP + units * DIFFSIM_BYTES_PER_UNIT_SUBSTEP
        per_slew_step = substeps * per_substep + DIFFSIM_BYTES_PER_STEP
        window = d.batch_size * d.window_steps * per_slew_step
        design = relaxed = 0
        if codesign:
            # A flight without a graph keeps one step's tensors a slew: at most what the window keeps
            # of an RK4 step, twice over for float64 (the validation slews of the kept design's
            # candidates, at most 1 + TOP_DRAWS = 4 of them).
            # A trade-off draws at least 4 designs a price, and flies every price's candidates at the end.
            prices = len(spec.objective.trade_off_prices_s_per_kg)
            draws = max(d.design_batch, 4 * prices)
            finals = 4 * max(1, prices) + (TRADE_OFF_EXTRA_CANDIDATES if prices else 0)
            flights = max(draws * d.design_slews, finals * e.episodes)
            design = 2 * per_substep * flights
            if d.design_gradient == "relaxed":  # a whole episode's graph, float64
                relaxed = m.episode_steps * (2 * d.design_slews * per_slew_step + RELAXED_BYTES_PER_STEP)
        return Estimate(
            design_bytes=design,
            relaxed_bytes=relaxed,
            replay_bytes=0,
            update_bytes=window,
            step_bytes=0,
            evaluation_bytes=evaluation,
            train_env_steps=t.total_env_steps,
            evaluation_steps=evaluation_steps,
        )
    return Estimate(
        replay_bytes=replay_capacity(t) * transition_bytes(N, t.observe_last_command),
        update_bytes=update,
        step_bytes=step,
        evaluation_bytes=evaluation,
        train_env_steps=t.total_env_steps,
        evaluation_steps=evaluation_steps,
    )


#: One batched RK4 step's fixed cost, seconds (torch's per-call overhead: `bench sim` at B = 1 flies
#: 43-82 control steps/s of 20 RK4 steps, 0.6-1.2 ms each).
CALL_S = 1.2e-3
#: ... plus per satellite (`bench sim` at B = 256 and 4096: 0.7-1.1 us) ...
SAT_SUBSTEP_S = 1.5e-6
#: ... plus per satellite and wheel-unit slot (`bench sim` at B = 256 with 8 to 900 slots: 21 ns).
SLOT_SUBSTEP_S = 4e-8
#: An RK4 step inside a gradient window (`diffsim`): forward, the graph and the backward pass.
GRAD_FACTOR = 3
#: Network floating-point operations per second on one core (`bench update`: the per-module network's
#: update on 3^3 and 5^3 grids runs at ~74 GFLOP/s counted as :data:`_UPDATE_PASSES` passes).
FLOPS = 40e9
#: A TD3 update's fixed cost (`bench update`: the flat network's update, 6.6 ms), and an env step
#: batch's (features, the actor's call, the replay row).
UPDATE_CALL_S = 8e-3
STEP_CALL_S = 3e-3
#: A GA design's fixed cost: a new TD3 or first-order run (networks, optimisers, replay buffer).
DESIGN_SETUP_S = 2.0
#: A checkpoint: serialised in the training process, sent to its worker, written to the database.
CHECKPOINT_S = 0.5
CHECKPOINT_BYTES_PER_S = 50e6
#: The largest replay buffer a checkpoint carries (``CHECKPOINT_BUFFER_LIMIT_BYTES``, training/checkpoint.py).
CHECKPOINT_BUFFER_BYTES = 256 * 2**20
#: Designs a trade-off flies at the end (per price the mode and ``TOP_DRAWS`` = 3 best draws, and
#: ``ARCHIVE_CANDIDATES`` = 16 points of the archive and ``SEARCH_CANDIDATES`` = 16 of the local search's
#: front); a single-price co-design flies 1 + 3.
TRADE_OFF_EXTRA_CANDIDATES = 32
#: The trade-off's local search (`diffsim.front_search_designs`) flies at most this many designs a round.
FRONT_SEARCH_ROUND = 32
HOUR = 3600.0


@dataclass(frozen=True)
class Limits:
    """What one run may use. ``None`` = no limit."""

    max_memory_bytes: int | None = 8 * GIB
    max_env_steps: int | None = 20_000_000
    max_evaluation_steps: int | None = 50_000_000
    max_trajectory_steps: int | None = 200_000
    #: Estimated wall time of one run (:func:`work`), hours on one CPU core, or on
    #: ``gpu_speedup`` times that speed for a run that may use a GPU.
    max_job_hours: float | None = 48.0
    #: How much faster this deployment's workers run a job whose ``training.device`` is `auto` or
    #: `cuda` than one CPU core; 1 = no GPU (such jobs are then estimated as CPU jobs).
    gpu_speedup: float = 30.0
    #: Checkpoints one run may write (``training.total_env_steps / training.checkpoint_every_steps``).
    max_checkpoints: int | None = 1000


def _mlp_flops(widths: list[int]) -> int:
    """Floating-point operations of one forward pass of a dense network of these layer widths."""
    return 2 * sum(a * b for a, b in itertools.pairwise(widths))


def td3_sample_flops(spec: JobSpec) -> int:
    """One forward pass of the TD3 actor (the critics are of the same size) for one satellite."""
    t = spec.training
    C, h = spec.design.grid_size**3, list(t.hidden_sizes)
    F = N_FEATURES + (N_LAST_COMMAND if t.observe_last_command else 0)
    if t.network == "per-module":  # the trunk on every cell, two heads
        return C * (_mlp_flops([F + 3, *h, 3]) + 2 * h[-1] * 3)
    W = SET_CELL_WIDTH  # a per-cell encoder, the wide layers once, per-cell heads
    return C * (_mlp_flops([F + 3, W, W]) + _mlp_flops([h[-1] + W, W, 3])) + _mlp_flops([W + 16, *h])


@dataclass(frozen=True)
class Work:
    """Estimated seconds on one CPU core, by part (:func:`work`)."""

    training_s: float  # the learner: TD3 updates and env steps, or the first-order windows
    evaluation_s: float  # the curve's evaluations and the final Monte-Carlo, policy and PD
    design_s: float = 0.0  # `diffsim-codesign`'s design flights
    setup_s: float = 0.0  # the GA's new runs, one per design
    checkpoint_s: float = 0.0
    updates: int = 0  # learner updates (TD3 updates, or first-order windows)

    @property
    def cpu_seconds(self) -> float:
        return self.training_s + self.evaluation_s + self.design_s + self.setup_s + self.checkpoint_s


def _substeps_s(batches: float, sats: float, slots: int, grad: bool = False) -> float:
    """Seconds of ``batches`` batched RK4 steps flying ``sats`` satellite-steps in all, ``slots``
    wheel-unit slots each."""
    s = batches * CALL_S + sats * (SAT_SUBSTEP_S + slots * SLOT_SUBSTEP_S)
    return GRAD_FACTOR * s if grad else s


def _slots(spec: JobSpec) -> int:
    fixed = spec.design.fixed_design
    if fixed is None or spec.algorithm in ("diffsim-codesign", "td3-codesign", "ga") or spec.diffsim.design_pool:
        return spec.design.grid_size**3  # the designs it flies may hold a unit in every cell
    return max(1, sum(c >= 2 for c in _cells(fixed)))


def work(spec: JobSpec) -> Work:
    """Estimated wall time of a run of ``spec`` on one CPU core, by part (see the module docstring)."""
    t, m, e = spec.training, spec.mission, spec.evaluation
    K, fs, T = _slots(spec), m.frame_skip, m.episode_steps
    conditions = len(e.conditions)
    ga = spec.algorithm == "ga"
    designs = max(1, t.total_env_steps // spec.ga.steps_per_design) if ga else 1
    per_design_steps = min(spec.ga.steps_per_design, t.total_env_steps) if ga else t.total_env_steps
    if is_diffsim(spec):
        d = spec.diffsim
        sub = fs if d.substeps is None else d.substeps
        window = d.batch_size * d.window_steps
        updates = designs * max(1, per_design_steps // window)
        batches = updates * d.window_steps * sub
        training = _substeps_s(batches, batches * d.batch_size, K, grad=True)
        hidden = [7 + 7, *d.hidden_sizes, 3 * K]  # the controller's state in, K wheel units' torques out
        training += GRAD_FACTOR * updates * window * _mlp_flops(hidden) / FLOPS
        policy_flops = _mlp_flops(hidden)
    else:
        env_batches = t.total_env_steps / t.num_envs
        training = env_batches * STEP_CALL_S + _substeps_s(env_batches * fs, t.total_env_steps * fs, K)
        sample = td3_sample_flops(spec)
        training += t.total_env_steps * sample / FLOPS
        learning = max(0, per_design_steps - t.learning_starts) * designs
        updates = learning // t.train_frequency
        training += updates * (UPDATE_CALL_S + t.batch_size * _UPDATE_PASSES * sample / FLOPS)
        policy_flops = sample
    # The curve: one batch of eval_episodes slews per point (per GA design); the final evaluation:
    # the nominal slews and every condition's, flown by the policy and by PD, for each final design.
    points = designs * (per_design_steps // t.eval_every_steps + 1)
    finals = 1
    design = 0.0
    if spec.algorithm == "diffsim-codesign":
        d = spec.diffsim
        prices = len(spec.objective.trade_off_prices_s_per_kg)
        finals = max(1, prices) * 4 + (TRADE_OFF_EXTRA_CANDIDATES if prices else 0)
        draws = max(d.design_batch, 4 * prices)
        design_updates = max(1, updates // d.design_every)
        sub = fs if d.substeps is None else d.substeps
        flights = design_updates * T * sub
        design = _substeps_s(flights, flights * draws * d.design_slews, K)
        design += design_updates * T * draws * d.design_slews * policy_flops / FLOPS
        if prices and d.front_search_designs:  # the local search's rounds, each one batch of flights
            rounds = 1 + -(-d.front_search_designs // FRONT_SEARCH_ROUND)
            sats = d.front_search_designs * d.design_slews * T * sub
            design += _substeps_s(rounds * T * sub, sats, K) + sats / sub * policy_flops / FLOPS
    curve_sats = points * t.eval_episodes * T
    final_sats = finals * 2 * e.episodes * (1 + conditions) * T
    batches = (points + finals * 4) * T * fs
    evaluation = _substeps_s(batches, (curve_sats + final_sats) * fs, K)
    evaluation += (curve_sats + final_sats) * policy_flops / FLOPS
    setup = designs * DESIGN_SETUP_S if ga else 0.0
    n_ckpt = min(t.total_env_steps // t.checkpoint_every_steps, updates if is_diffsim(spec) else t.total_env_steps)
    replay = (
        0
        if is_diffsim(spec)
        else min(
            CHECKPOINT_BUFFER_BYTES,
            replay_capacity(t) * transition_bytes(spec.design.grid_size, t.observe_last_command),
        )
    )
    checkpoint = n_ckpt * (CHECKPOINT_S + replay / CHECKPOINT_BYTES_PER_S)
    return Work(
        training_s=training,
        evaluation_s=evaluation,
        design_s=design,
        setup_s=setup,
        checkpoint_s=checkpoint,
        updates=int(updates),
    )


def job_hours(spec: JobSpec, limits: Limits) -> tuple[float, bool]:
    """Estimated hours of a run of ``spec`` where ``limits`` apply, and whether a GPU is credited."""
    gpu = spec.training.device in ("auto", "cuda") and limits.gpu_speedup > 1
    return work(spec).cpu_seconds / HOUR / (limits.gpu_speedup if gpu else 1.0), gpu


def _gib(n: int) -> str:
    return f"{n / GIB:.1f} GiB"


def check(spec: JobSpec, limits: Limits) -> list[tuple[tuple[str, ...], str]]:
    """Problems of ``spec`` under ``limits``: ``[(field path, message)]``, empty when it fits.

    The path names the field that drives the exceeded figure most, so that an API client
    (a 422 naming it) or a CLI user knows what to change."""
    est = estimate(spec)
    t, m, e = spec.training, spec.mission, spec.evaluation
    out: list[tuple[tuple[str, ...], str]] = []
    if limits.max_memory_bytes is not None and est.memory_bytes > limits.max_memory_bytes and est.replay_bytes == 0:
        d = spec.diffsim
        sizes = {
            ("diffsim", "batch_size"): est.update_bytes,
            ("diffsim", "design_batch"): est.design_bytes,
            ("diffsim", "design_slews"): est.relaxed_bytes,
            ("evaluation", "episodes"): est.evaluation_bytes,
        }
        loc = max(sizes, key=lambda k: sizes[k])
        out.append(
            (
                loc,
                (
                    f"{'.'.join(loc)}: this run would need about {_gib(est.memory_bytes)} of memory, more than this "
                    f"service allows ({_gib(limits.max_memory_bytes)}, MODSAT_MAX_JOB_MEMORY_GIB): one gradient "
                    f"window {_gib(est.update_bytes)} ({d.batch_size} slews x {d.window_steps} steps), evaluation "
                    f"{_gib(est.evaluation_bytes)}, designs flown at once {_gib(est.design_bytes)}"
                    + (f", the relaxed design flight {_gib(est.relaxed_bytes)}" if est.relaxed_bytes else "")
                    + "; "
                    f"lower {'.'.join(loc)}"
                ),
            )
        )
    elif limits.max_memory_bytes is not None and est.memory_bytes > limits.max_memory_bytes:
        parts = {
            ("training", "buffer_size"): est.replay_bytes,
            ("training", "batch_size"): est.update_bytes,
            ("training", "num_envs"): est.step_bytes,
            ("evaluation", "episodes"): est.evaluation_bytes,
        }
        loc = max(parts, key=lambda k: parts[k])
        out.append(
            (
                loc,
                (
                    f"{'.'.join(loc)}: this run would need about {_gib(est.memory_bytes)} of memory, more than this "
                    f"service allows ({_gib(limits.max_memory_bytes)}, MODSAT_MAX_JOB_MEMORY_GIB): replay buffer "
                    f"{_gib(est.replay_bytes)} ({replay_capacity(t):,} transitions of a "
                    f"{spec.design.grid_size}^3 grid), one update {_gib(est.update_bytes)} (batch {t.batch_size}), "
                    f"stepping {_gib(est.step_bytes)} "
                    f"({t.num_envs} envs), evaluation {_gib(est.evaluation_bytes)}; lower {'.'.join(loc)}"
                ),
            )
        )
    if limits.max_env_steps is not None and t.total_env_steps > limits.max_env_steps:
        out.append(
            (
                ("training", "total_env_steps"),
                (
                    f"training.total_env_steps: {t.total_env_steps:,} is more than this service runs in one job "
                    f"({limits.max_env_steps:,}, MODSAT_MAX_ENV_STEPS)"
                ),
            )
        )
    if limits.max_evaluation_steps is not None and est.evaluation_steps > limits.max_evaluation_steps:
        curve = (t.total_env_steps // t.eval_every_steps + 1) * t.eval_episodes
        final = 2 * e.episodes * (1 + len(e.conditions))
        loc = ("training", "eval_every_steps") if curve >= final else ("evaluation", "episodes")
        out.append(
            (
                loc,
                (
                    f"{'.'.join(loc)}: the evaluations would fly {est.evaluation_steps:,} control steps "
                    f"({curve:,} curve episodes and 2 x {e.episodes:,} x {1 + len(e.conditions)} final ones: "
                    f"nominal and {len(e.conditions)} evaluation.conditions; {m.episode_steps:,} steps each), "
                    f"more than this service allows ({limits.max_evaluation_steps:,}, MODSAT_MAX_EVALUATION_STEPS)"
                ),
            )
        )
    out += _work_problems(spec, limits)
    if limits.max_trajectory_steps is not None and e.trajectories * m.episode_steps > limits.max_trajectory_steps:
        out.append(
            (
                ("evaluation", "trajectories"),
                (
                    f"evaluation.trajectories: {e.trajectories} recorded slews of {m.episode_steps:,} steps are "
                    f"{e.trajectories * m.episode_steps:,} recorded steps, more than this service stores "
                    f"({limits.max_trajectory_steps:,}, MODSAT_MAX_TRAJECTORY_STEPS)"
                ),
            )
        )
    return out


def _work_problems(spec: JobSpec, limits: Limits) -> list[tuple[tuple[str, ...], str]]:
    """The work bound (:func:`work`), the checkpoints' count and a GA whose first generation does not fit its budget."""
    t = spec.training
    out: list[tuple[tuple[str, ...], str]] = []
    first = spec.ga.population_size * spec.ga.steps_per_design
    cap = limits.max_env_steps
    if spec.algorithm == "ga" and cap is not None and first > max(cap, t.total_env_steps):
        g = spec.ga
        out.append(
            (
                ("ga", "population_size"),
                f"ga.population_size: {g.population_size:,} designs of {g.steps_per_design:,} env steps "
                f"(ga.steps_per_design) are {first:,} env steps for the first generation alone, more than the "
                f"run's budget (training.total_env_steps {t.total_env_steps:,}) and than this service runs in one "
                f"job ({cap:,}, MODSAT_MAX_ENV_STEPS): the GA would never select; lower ga.population_size",
            )
        )
    hours, gpu = job_hours(spec, limits)
    if limits.max_job_hours is not None and hours > limits.max_job_hours:
        out.append(_hours_problem(spec, limits, hours, gpu))
    n_ckpt = t.total_env_steps // t.checkpoint_every_steps
    if limits.max_checkpoints is not None and n_ckpt > limits.max_checkpoints:
        out.append(
            (
                ("training", "checkpoint_every_steps"),
                f"training.checkpoint_every_steps: {t.checkpoint_every_steps:,} would write {n_ckpt:,} checkpoints "
                f"over {t.total_env_steps:,} env steps, more than this service stores for one job "
                f"({limits.max_checkpoints:,}, MODSAT_MAX_CHECKPOINTS); raise it",
            )
        )
    return out


def _hours_problem(spec: JobSpec, limits: Limits, hours: float, gpu: bool) -> tuple[tuple[str, ...], str]:
    t, w = spec.training, work(spec)
    parts = {
        ("training", "total_env_steps"): w.training_s + w.setup_s,
        ("evaluation", "episodes"): w.evaluation_s,
        ("diffsim", "design_slews"): w.design_s,
        ("training", "checkpoint_every_steps"): w.checkpoint_s,
    }
    loc = max(parts, key=lambda k: parts[k])
    if loc == ("evaluation", "episodes") and w.evaluation_s and spec.algorithm != "diffsim-codesign":
        final = 2 * spec.evaluation.episodes * (1 + len(spec.evaluation.conditions))
        points = t.total_env_steps // t.eval_every_steps + 1
        if points * t.eval_episodes > final:
            loc = ("training", "eval_every_steps")
    verb = "raise" if loc == ("training", "checkpoint_every_steps") or loc[-1] == "eval_every_steps" else "lower"
    where = f"{limits.gpu_speedup:g}x one CPU core (a GPU, MODSAT_GPU_SPEEDUP)" if gpu else "one CPU core"
    assert limits.max_job_hours is not None
    return (
        loc,
        f"{'.'.join(loc)}: this run would take about {hours:,.1f} h on {where}, more than this service "
        f"allows for one job ({limits.max_job_hours:g} h, MODSAT_MAX_JOB_HOURS): training "
        f"{w.training_s / HOUR:,.1f} h ({w.updates:,} updates), evaluations {w.evaluation_s / HOUR:,.1f} h"
        + (f", design flights {w.design_s / HOUR:,.1f} h" if w.design_s else "")
        + (f", {w.setup_s / HOUR:,.1f} h starting GA designs" if w.setup_s else "")
        + f", checkpoints {w.checkpoint_s / HOUR:,.1f} h (one-core hours); {verb} {'.'.join(loc)}",
    )


def _cells(grid: list) -> list[int]:
    """The cells of a nested-list design, flattened."""
    return [c for plane in grid for row in plane for c in row]
