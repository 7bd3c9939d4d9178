"""`diffsim-control`: a controller learned by backpropagating a mission cost through the simulator.

The batched :class:`~modsat_core.sim.slew.SlewSim` is torch from end to end, so the cost of a
stretch of flight is a differentiable function of the controller's weights. Each update flies
``diffsim.batch_size`` slews for ``window_steps`` control steps with the controller in the loop,
backpropagates the window's cost through every step (short-horizon backpropagation through time,
as SHAC does without its critic), clips the gradient's norm and takes an Adam step; the state is
then detached and the next window continues the same flights. Slews end after ``episode_steps``
control steps or a rate-limit violation, at a window's end, and new ones are drawn.

Cost of a step, from the state after it (phi: error angle, w: |omega_B|, both smoothed near zero)::

    phi + rate_weight w + angle_log_weight log(1 + phi / angle_log_scale_rad)
        + rate_log_weight log(1 + w / rate_log_scale_rad_s) + barrier_weight relu(w - w_b)^2

with ``w_b = rate_barrier_fraction * rate_limit``. The log terms keep a gradient pulling into
the tolerance cone and to rest where the linear terms are flat; the window's last step counts
``terminal_weight`` extra times. Training flies a coarser integrator (``diffsim.substeps`` RK4
steps per control step; the control interval is the mission's); the curve and the final
evaluation fly the mission's own physics.

The controller is the design's PD law plus the network's correction (``diffsim.base`` `pd`, the
default; the gradient flows through the PD law too) or the network alone (`none`); with
``diffsim.design_pool`` its training slews fly random designs too (:meth:`DiffsimRun.initial_pool`).

With the spec's ``randomise`` section each training slew flies under conditions drawn for it
(sensor noise, delay, inertia error, weak wheels, tumble, disturbance; docs/robustness.md) through
:class:`~modsat_core.sim.conditions.Flight`, and the gradient flows through them.

The budget (``training.total_env_steps``) counts control steps flown in training: one update is
``batch_size * window_steps`` of them. docs/diffsim.md has the settings and the measurements.
"""

from __future__ import annotations

import copy
import math
from typing import cast

import numpy as np
import torch
from torch import Tensor

from modsat_core.agent.diffsim_policy import DiffsimController, DiffsimPolicy
from modsat_core.agent.policy_file import actor_from_state, new_actor
from modsat_core.artefacts import ProgressRecord
from modsat_core.evaluation.run_files import curve_point
from modsat_core.evaluation.selection import keep, validate
from modsat_core.grid import random_valid_design
from modsat_core.sim.conditions import Flight
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim, slot_masks
from modsat_core.spec.diffsim import Diffsim
from modsat_core.spec.jobspec import JobSpec, Mission
from modsat_core.training.callbacks import CheckpointFn, ProgressFn, StopFn
from modsat_core.training.checkpoint import to_cpu


def training_mission(mission: Mission, substeps: int | None) -> Mission:
    """The mission flown in training: the same control interval on ``substeps`` RK4 steps."""
    if substeps is None or substeps == mission.frame_skip:
        return mission
    return mission.model_copy(update={"physics_dt_s": mission.control_dt_s / substeps, "frame_skip": substeps})


def _smooth_norm(v: Tensor, eps: float = 1e-8) -> Tensor:
    return torch.sqrt((v * v).sum(dim=-1) + eps)


def step_cost(sim: SlewSim, d: Diffsim) -> Tensor:
    """(B,) cost of the satellites' current state (see the module docstring)."""
    q = sim.error_quaternion()
    phi = 2.0 * torch.atan2(_smooth_norm(q[:, 1:]), q[:, 0])
    w = _smooth_norm(sim.state.omega_B)
    barrier = d.rate_barrier_fraction * sim.mission.rate_limit_rad_s
    return (
        phi
        + d.rate_weight * w
        + d.angle_log_weight * torch.log1p(phi / d.angle_log_scale_rad)
        + d.rate_log_weight * torch.log1p(w / d.rate_log_scale_rad_s)
        + d.barrier_weight * torch.relu(w - barrier) ** 2
    )


def window_loss(sim: SlewSim, controller: DiffsimController, d: Diffsim, flight: Flight | None = None) -> Tensor:
    """Fly ``window_steps`` control steps from the sim's state and return the window's mean cost
    (a scalar with the graph of every step); with ``flight``, under its rows' conditions (the cost is
    the true state's)."""
    total = torch.zeros((), dtype=sim.dtype, device=sim.device)
    cost = total
    for _ in range(d.window_steps):
        if flight is None:
            sim.step(controller(sim))
        else:
            flight.step(controller)
        cost = step_cost(sim, d)
        total = total + cost.mean()
    return (total + d.terminal_weight * cost.mean()) / (d.window_steps + d.terminal_weight)


class DiffsimRun:
    """One `diffsim-control` run: the controller, its optimiser, the training flights, the curve."""

    def __init__(self, spec: JobSpec, device: str = "cpu"):
        self.spec, self.d, self.t, self.device = spec, spec.diffsim, spec.training, device
        torch.manual_seed(spec.seed)
        self.policy = cast(DiffsimPolicy, new_actor(spec)).to(device)
        self.controller = DiffsimController(self.policy, spec.mission.rate_limit_rad_s, self.d.base)
        self.opt = torch.optim.Adam(self.policy.parameters(), lr=self.d.lr)
        B = self.d.batch_size
        self.rng = np.random.default_rng([spec.seed, 1])
        self.grid, grids = self.initial_pool()
        self.pool = [Design.from_grid(g, spec.modules) for g in grids]
        self.active = (0, len(self.pool))  # the pool's slice a new training slew draws its design from
        self.row_design = torch.zeros(B, dtype=torch.long)
        if len(self.pool) > 1:
            self.row_design = torch.as_tensor(self.rng.integers(0, len(self.pool), size=B), dtype=torch.long)
            # Row 0 starts on the design with the most wheel units: the simulator's unit slots are
            # sized by its first designs (and grow when a later one carries more, fly_designs).
            self.row_design[0] = int(np.argmax([d.n_actuators for d in self.pool]))
        self.sim = SlewSim.from_designs(
            [self.pool[i] for i in self.row_design.tolist()],
            training_mission(spec.mission, self.d.substeps),
            spec.modules,
            dtype=torch.float32,
            device=device,
            compiled=self.d.compiled,
        )
        W, T = self.d.window_steps, self.d.episode_steps
        # Staggered first slews: row i's first slew ends after a random whole number of windows,
        # so that later windows hold slews at every stage.
        windows = max(1, math.ceil(T / W))
        self.ep_steps = torch.as_tensor(self.rng.integers(0, windows, size=B) * W, dtype=torch.long)
        # Domain randomisation (the `randomise` section): the flight between controller and sim.
        self.flight = Flight(
            self.sim, max_delay=spec.randomise.delay_steps if spec.randomise.active else 0, seed=spec.seed
        )
        self.start_slews(torch.arange(B))
        self.env_steps = 0
        self.updates = 0
        self.curve: list[dict] = []
        self.kept: list[dict] = []
        self.last: dict[str, float] = {}
        self.next_eval = self.t.eval_every_steps
        self.next_ckpt = self.t.checkpoint_every_steps

    def initial_pool(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """The design the curve flies, and the designs training flies: the run's, and with a pool,
        random valid ones (drawn from a stream of their own, so that the pool is the same whatever
        the flights draw)."""
        assert self.spec.design.fixed_design is not None  # the spec's validator requires it
        grid = np.asarray(self.spec.design.fixed_design, dtype=np.int64)
        pool_rng = np.random.default_rng([self.spec.seed, 2])
        N = self.spec.design.grid_size
        return grid, [grid] + [random_valid_design(pool_rng, N) for _ in range(self.d.design_pool)]

    # ------------------------------------------------------------------ schedule
    @property
    def steps_per_update(self) -> int:
        return self.d.batch_size * self.d.window_steps

    @property
    def total_updates(self) -> int:
        return max(1, self.t.total_env_steps // self.steps_per_update)

    def lr(self, update: int) -> float:
        """Cosine from ``lr`` to ``lr_final`` over the run's updates."""
        frac = min(1.0, update / max(1, self.total_updates - 1))
        return self.d.lr_final + 0.5 * (self.d.lr - self.d.lr_final) * (1.0 + math.cos(math.pi * frac))

    # ------------------------------------------------------------------ one update
    def update(self) -> dict[str, float]:
        for group in self.opt.param_groups:
            group["lr"] = self.lr(self.updates)
        self.policy.train()
        loss = window_loss(self.sim, self.controller, self.d, self.flight)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = float(torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.d.grad_clip))
        self.opt.step()
        self.flight.detach()
        self.updates += 1
        self.env_steps += self.steps_per_update
        self.ep_steps += self.d.window_steps
        ended = (self.ep_steps >= self.d.episode_steps) | self.sim.metrics.violated.cpu()
        idx = torch.nonzero(ended).flatten()
        if len(idx):
            if len(self.pool) > 1:
                self.row_design[idx] = torch.as_tensor(self.rng.integers(*self.active, size=len(idx)))
                self.fly_designs(idx)
            self.start_slews(idx)
            self.ep_steps[idx] = 0
        self.last = {"loss": float(loss.detach()), "grad_norm": grad_norm}
        return self.last

    def start_slews(self, idx: Tensor) -> None:
        """New training slews on rows ``idx`` (on their designs); with `randomise`, each under
        conditions drawn for it: the sim flies the true inertia, the controller knows the design's."""
        n = len(idx)
        draws = [draw_episode(self.rng, self.spec.mission) for _ in range(n)]
        r = self.spec.randomise
        if r.active:
            I_model = np.stack([self.pool[i].I_B for i in self.row_design[idx].tolist()])
            draws = self.flight.randomise(idx, r, self.rng, I_model, draws)
        self.sim.reset(idx.tolist(), draws)
        self.flight.reset_rows(idx)

    def fly_designs(self, idx: Tensor) -> None:
        """Put rows ``idx`` on their designs of the pool (``row_design``)."""
        designs = [self.pool[i] for i in self.row_design[idx].tolist()]
        self.flight.grow_slots(max(d.n_actuators for d in designs))
        K = self.sim.plant.actuator_mask.shape[1]
        packed, momentum = slot_masks(designs, bool(self.spec.modules.wheels))
        mask = np.zeros((len(designs), K), dtype=packed.dtype)
        mask[:, : packed.shape[1]] = packed
        mw = None
        if momentum is not None:
            mw = np.zeros((len(designs), K))
            mw[:, : momentum.shape[1]] = momentum
        I_B = torch.as_tensor(np.stack([d.I_B for d in designs]))
        dev = self.sim.device
        self.sim.set_plants(
            idx.to(dev), I_B.to(dev), torch.as_tensor(mask).to(dev), None if mw is None else torch.as_tensor(mw).to(dev)
        )

    # ------------------------------------------------------------------ the run
    def run(self, on_progress: ProgressFn, on_checkpoint: CheckpointFn, should_stop: StopFn) -> bool:
        """Train to the end of the budget; True if stopped by ``should_stop`` (after a checkpoint)."""
        total = self.t.total_env_steps
        while self.env_steps + self.steps_per_update <= total:
            if should_stop():
                on_checkpoint(self.state_dict())
                return True
            self.update()
            point = None
            last = self.env_steps + self.steps_per_update > total
            if self.env_steps >= self.next_eval or last:
                point = self.evaluate_now()
                self.next_eval = (self.env_steps // self.t.eval_every_steps + 1) * self.t.eval_every_steps
            on_progress(self.progress(point))
            if self.env_steps >= self.next_ckpt and not last:
                on_checkpoint(self.state_dict())
                self.next_ckpt = (self.env_steps // self.t.checkpoint_every_steps + 1) * self.t.checkpoint_every_steps
        if not self.kept:  # a budget smaller than one update: the untrained controller
            on_progress(self.progress(self.evaluate_now()))
        return False

    def evaluate_now(self) -> dict:
        """A learning-curve point: a CPU copy of the controller on the curve's slews (the mission's
        physics), and the last update's cost and gradient norm."""
        policy = copy.deepcopy(self.policy).cpu().eval()
        point = curve_point(policy, self.grid, self.spec, self.env_steps, self.updates, 0.0)
        point.update(self.last)
        self.curve.append(point)
        self.kept = keep(self.kept, point, policy, self.grid, self.t.select_top_k)
        return point

    def progress(self, point: dict | None) -> dict:
        out = {
            "env_steps": self.env_steps,
            "total_env_steps": self.t.total_env_steps,
            "updates": self.updates,
            "phase": "training",
            "eval": point,
            **self.last,
        }
        return ProgressRecord.model_validate(out).to_dict()

    def chosen(self) -> tuple[torch.nn.Module, np.ndarray, dict]:
        """The controller the final evaluation flies (as TD3's: the curve's best, or the best of its
        top ``select_top_k`` on validation slews), its design and the record of the choice."""
        snapshot, scores = validate(self.kept, self.spec)
        extra: dict = {"best_env_steps": snapshot["env_steps"]}
        if scores:
            extra["selection"] = scores
        return actor_from_state(self.spec, snapshot["actor"]), self.grid, extra

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        return {
            "env_steps": self.env_steps,
            "updates": self.updates,
            "next_eval": self.next_eval,
            "next_ckpt": self.next_ckpt,
            "curve": copy.deepcopy(self.curve),
            "kept": self.kept,
            "last": dict(self.last),
            "policy": to_cpu(self.policy.state_dict()),
            "opt": to_cpu(self.opt.state_dict()),
            "rng": self.rng.bit_generator.state,
            "ep_steps": self.ep_steps.clone(),
            "row_design": self.row_design.clone(),
            "sim": self.sim.flight_state(),
            "flight": self.flight.state_dict(),
        }

    def load_state_dict(self, d: dict) -> None:
        self.env_steps, self.updates = d["env_steps"], d["updates"]
        self.next_eval, self.next_ckpt = d["next_eval"], d["next_ckpt"]
        self.curve, self.kept, self.last = list(d["curve"]), list(d["kept"]), dict(d["last"])
        for s in self.kept:  # the grid is a list in a checkpoint's bytes (weights_only loading)
            s["grid"] = np.asarray(s["grid"], dtype=np.int64)
        self.policy.load_state_dict(d["policy"])
        self.opt.load_state_dict(d["opt"])
        self.rng.bit_generator.state = d["rng"]
        self.ep_steps = torch.as_tensor(d["ep_steps"], dtype=torch.long)
        self.flight.grow_slots(d["sim"]["h_B"].shape[1])  # the slots the flights had grown to
        if len(self.pool) > 1:
            self.row_design = torch.as_tensor(d["row_design"], dtype=torch.long)
            self.fly_designs(torch.arange(len(self.row_design)))
        self.sim.load_flight(d["sim"])
        if "flight" in d:  # checkpoints written before domain randomisation have none (and need none)
            self.flight.load_state_dict(d["flight"])
