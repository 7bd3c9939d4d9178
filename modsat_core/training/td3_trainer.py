"""One TD3 run on the batched co-design MDP (or control of a fixed design): acting with
exploration, the replay buffer, updates, learning-curve evaluations, the snapshot kept for
the final evaluation, and its checkpoint state. Also the GA's inner loop, and the loop of
``modsat bench control`` (the flat networks on a fixed design, its own evaluations).
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from modsat_core.agent.flat_networks import FlatCellActor, FlatCellCritic
from modsat_core.agent.layers import finish
from modsat_core.agent.networks import make_critic
from modsat_core.agent.policy import design_with
from modsat_core.agent.policy_file import actor_from_state, n_features_of, new_actor
from modsat_core.agent.td3 import TD3, ReplayBuffer, TD3Config
from modsat_core.artefacts import ProgressRecord
from modsat_core.codesign.features import CellObs
from modsat_core.codesign.mdp import CoDesignEnv, Compact, EnvStep, next_last_command, observe_compact
from modsat_core.evaluation.run_files import curve_point
from modsat_core.evaluation.selection import keep, validate
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.limits import replay_capacity
from modsat_core.training.callbacks import CheckpointFn, ProgressFn, StopFn
from modsat_core.training.checkpoint import CHECKPOINT_BUFFER_LIMIT_BYTES, to_cpu, to_device
from modsat_core.training.replay_layout import replay_fields


class TD3Run:
    """One TD3 training run on the batched MDP (co-design, or control of a fixed design).

    ``flat``: the flat MLP pair of ``modsat bench control`` (:class:`FlatCellActor`) instead of
    the spec's co-design network, on a fixed design; the bench drives :meth:`step` and evaluates
    on its own (:meth:`run`'s curve, selection and files expect the spec's network)."""

    def __init__(self, spec: JobSpec, *, fixed_grid: np.ndarray | None = None, device: str = "cpu", flat: bool = False):
        if fixed_grid is None and spec.algorithm == "td3-control":
            fixed_grid = np.asarray(spec.design.fixed_design)
        if flat and fixed_grid is None:
            raise ValueError("the flat networks fly a fixed design: give fixed_grid")
        self.spec, self.t = spec, spec.training
        self.device = device
        self.fixed_grid = None if fixed_grid is None else np.asarray(fixed_grid, dtype=np.int64)
        self.env = CoDesignEnv(spec, self.t.num_envs, seed=spec.seed, fixed_grid=self.fixed_grid, device=device)
        torch.manual_seed(spec.seed)
        hidden = list(self.t.hidden_sizes)
        actor: torch.nn.Module
        critic: torch.nn.Module
        if flat and self.fixed_grid is not None:
            if self.t.observe_last_command or self.t.randomise_after_success is not None:
                raise ValueError(
                    "the flat TD3 controller (modsat bench control) neither observes its last command nor "
                    "follows the randomise curriculum: set training.observe_last_command false and "
                    "training.randomise_after_success null"
                )
            actor = FlatCellActor(self.fixed_grid, hidden, self.t.odd_control)
            critic = FlatCellCritic(self.fixed_grid, hidden)
        else:
            actor, critic = new_actor(spec), make_critic(self.t.network, n_features_of(self.t), hidden)
        self.agent = TD3(actor.to(device), critic.to(device), TD3Config.from_training(self.t))
        self.last_command = self.t.observe_last_command
        fields = replay_fields(self.env.N, self.last_command)
        self.buffer = ReplayBuffer(fields, replay_capacity(self.t), device=device)
        self.gen = torch.Generator(device=device).manual_seed(spec.seed)
        self.cpu_gen = torch.Generator().manual_seed(spec.seed + 1)
        self.rng = np.random.default_rng([spec.seed, 3])
        self.env_steps = 0
        self.update_credit = 0.0
        self.next_eval = self.t.eval_every_steps
        self.next_ckpt = self.t.checkpoint_every_steps
        self.curve: list[dict] = []
        # The curve's best snapshots, best first, at most `select_top_k`: {"mean_return",
        # "success_rate", "env_steps", "grid", "actor"} (selection.py).
        self.kept: list[dict] = []
        self.recent: list[dict] = []  # finished training episodes since the last progress call
        self.last_info: dict = {}
        self.explore_design = torch.ones(self.env.B, dtype=torch.bool, device=device)
        self.env.randomising = self.randomising()

    # ------------------------------------------------------------------ acting
    def _act(self, obs: CellObs) -> torch.Tensor:
        B, C = obs.x.shape[0], obs.x.shape[1]
        warm_up = self.env_steps < self.t.learning_starts
        if warm_up and not bool(obs.design.any()):
            a = torch.zeros((B, C, 3), device=self.device)  # every row flies: replaced by random torques below
        else:
            with torch.no_grad():
                a = self.agent.actor(obs)
        noise = torch.randn(a.shape, generator=self.gen, device=self.device) * self.t.noise_at(self.env_steps)
        explore = self._explored_designs(obs)
        # Designing rows of an episode whose design is not explored grow the policy's own design.
        a = a + noise * (~obs.design | explore).reshape(B, 1, 1)
        p_swap = self.t.design_exploration_at(self.env_steps)
        if bool(obs.design.any()) and p_swap > 0:
            # Design exploration: a cell's type is replaced by a random one.
            swap = torch.rand((B, C, 1), generator=self.gen, device=self.device) < p_swap
            swap &= (obs.design & explore).reshape(B, 1, 1)
            rand = torch.rand((B, C, 3), generator=self.gen, device=self.device) * 2.0 - 1.0
            a = torch.where(swap, rand, a)
        if warm_up:
            # Before learning starts the flights are flown with uniformly random torques, on the
            # designs the (untrained) policy grows: random designs there (the paper's uniform
            # random actions in both phases) are mostly unflyable, and left the critic with
            # almost no flight data of the designs it then had to fly (docs/learning.md).
            rand = torch.rand((B, C, 3), generator=self.gen, device=self.device) * 2.0 - 1.0
            a = torch.where(obs.design.reshape(B, 1, 1), a, rand)
        return finish(obs, a)

    def _explored_designs(self, obs: CellObs) -> torch.Tensor:
        """(B,) bool: the episodes whose design phase is explored (`design_exploration_episodes`).

        Drawn once per episode, when its design phase starts; none while the design is held
        with `design_exploration_after_release`."""
        if self.t.design_exploration_after_release and not self.design_released():
            return torch.zeros_like(obs.design)
        q = self.t.design_exploration_episodes
        if q >= 1.0:
            return torch.ones_like(obs.design)
        starting = obs.design & (self.env.design_step == 0)
        if bool(starting.any()):
            draw = torch.rand(self.env.B, generator=self.gen, device=self.device) < q
            self.explore_design = torch.where(starting, draw, self.explore_design)
        return self.explore_design

    def current_grid(self) -> np.ndarray:
        if self.fixed_grid is not None:
            return self.fixed_grid
        return design_with(self._eval_actor(), self.spec.design, self.spec.mission)

    def _cpu_actor(self) -> torch.nn.Module:
        a = copy.deepcopy(self.agent.actor).cpu()
        a.eval()
        return a

    def _eval_actor(self) -> torch.nn.Module:
        return self.agent.actor if self.device == "cpu" else self._cpu_actor()

    # ------------------------------------------------------------------ loop
    def run(
        self, on_progress: ProgressFn, on_checkpoint: CheckpointFn, should_stop: StopFn, budget: int | None = None
    ) -> bool:
        """Train until the budget is spent; returns True if ``should_stop`` ended it early."""
        total = self.t.total_env_steps if budget is None else budget
        B = self.env.B
        progress_every = max(B, total // 200)
        next_progress = (self.env_steps // progress_every + 1) * progress_every
        # Steps come in batches of B; a batch that would overrun the budget is not taken.
        while self.env_steps + B <= total:
            if should_stop():
                on_checkpoint(self.state_dict())
                return True
            self.recent.extend(self.step().finished)
            point = None
            last = self.env_steps + B > total
            if self.env_steps >= self.next_eval or last:
                point = self.evaluate_now()
                self.next_eval = (self.env_steps // self.t.eval_every_steps + 1) * self.t.eval_every_steps
            if point is not None or self.env_steps >= next_progress:
                on_progress(self.progress(total, point))
                next_progress = (self.env_steps // progress_every + 1) * progress_every
            if self.env_steps >= self.next_ckpt and not last:
                on_checkpoint(self.state_dict())
                self.next_ckpt = (self.env_steps // self.t.checkpoint_every_steps + 1) * self.t.checkpoint_every_steps
        if not self.kept:  # a budget smaller than one batch: the untrained policy
            on_progress(self.progress(total, self.evaluate_now()))
        return False

    def step(self) -> EnvStep:
        """One batch of B env steps with exploration, into the replay, and the updates they earn
        (`train_frequency`, from `learning_starts`)."""
        N, D, rl = self.env.N, self.env.D, self.spec.mission.rate_limit_rad_s
        obs_c = self.env.compact()
        action = self._act(observe_compact(obs_c, N, D, rl))
        st = self.env.step(action)
        row = {
            **obs_c.as_dict("obs_"),
            **st.next_state.as_dict("next_"),
            "action": action,
            "reward": st.reward,
            "terminal": st.terminal,
        }
        if self.last_command:
            assert obs_c.last_cmd is not None
            row["obs_last_cmd"] = obs_c.last_cmd
        self.buffer.add(row)
        self.env_steps += self.env.B
        if self.env_steps >= self.t.learning_starts and self.buffer.size >= self.t.batch_size:
            self.update_credit += self.env.B / self.t.train_frequency
            while self.update_credit >= 1.0:
                self.update_credit -= 1.0
                self._update()
        return st

    def _update(self) -> None:
        b = self.buffer.sample(self.t.batch_size, self.gen)
        N, D, rl = self.env.N, self.env.D, self.spec.mission.rate_limit_rad_s
        # One feature pass over both halves of the transitions (half the small ops of two).
        pair = {k: torch.cat((b["obs_" + k], b["next_" + k])) for k in Compact.FIELDS}
        last = None
        if self.last_command:  # the next state's last command is this transition's action
            last = torch.cat((b["obs_last_cmd"], next_last_command(b["obs_design_step"], b["action"], D)))
        both = observe_compact(Compact.from_dict(pair, last_cmd=last), N, D, rl)
        n = self.t.batch_size
        obs, nxt = both.rows(0, n), both.rows(n, 2 * n)
        action = b["action"].float()
        # While the design layers are held the controller learns to fly the design the policy
        # starts from (and the explored ones near it) before the design moves.
        actor_rows = None if self.design_released() else ~obs.design
        self.last_info = self.agent.update(obs, action, b["reward"], nxt, b["terminal"], self.gen, actor_rows)

    @property
    def updates(self) -> int:
        return self.agent.updates

    def design_released(self) -> bool:
        """Whether the actor's design layers learn: after `design_learning_starts` env steps and,
        with `design_learning_after_success`, once an evaluation on the curve has landed that
        share of its slews (read from the curve, so a resumed run keeps the gate's state)."""
        if self.env_steps < self.t.design_learning_starts:
            return False
        gate = self.t.design_learning_after_success
        return gate is None or any(p.get("success_rate", 0.0) >= gate for p in self.curve)

    def randomising(self) -> bool:
        """Whether new training flights draw their conditions from `randomise`: with it active, from the
        start or, with `randomise_after_success`, once an evaluation on the curve has landed that share of
        its slews (read from the curve, so a resumed run keeps the switch)."""
        if not self.spec.randomise.active:
            return False
        gate = self.t.randomise_after_success
        return gate is None or any(p.get("success_rate", 0.0) >= gate for p in self.curve)

    def evaluate_now(self) -> dict:
        actor = self._eval_actor()
        grid = self.current_grid()
        point = curve_point(actor, grid, self.spec, self.env_steps, self.agent.updates, self.env.penalty)
        # Whether the flights since the last point were randomised: once they were, the snapshots of the
        # nominal training before it (the curriculum's first part) are not what the run ships.
        randomised = self.env.randomising
        if randomised:
            self.kept = [s for s in self.kept if s.get("randomised", True)]
        self.curve.append(point)
        self.kept = keep(self.kept, point, actor, grid, self.t.select_top_k)
        for s in self.kept:
            s.setdefault("randomised", randomised)
        self.env.randomising = self.randomising()
        return point

    def progress(self, total: int, point: dict | None) -> dict:
        recent, self.recent = self.recent, []
        out = {
            "env_steps": self.env_steps,
            "total_env_steps": total,
            "updates": self.agent.updates,
            "phase": "training",
            "eval": point,
        }
        if recent:
            out["train_episodes"] = len(recent)
            out["train_mean_return"] = float(np.mean([r["return"] for r in recent]))
            out["train_valid_rate"] = float(np.mean([r["valid"] for r in recent]))
            out["train_success_rate"] = float(np.mean([bool(r.get("success")) for r in recent]))
        for k in ("critic_loss", "actor_loss", "q"):
            if k in self.last_info:
                out[k] = self.last_info[k]
        return ProgressRecord.model_validate(out).to_dict()

    def chosen(self) -> tuple[torch.nn.Module, np.ndarray, dict]:
        """The policy the final evaluation flies, its design, and ``curve.json``'s record of the
        choice: the curve's best or, with `select_top_k` > 1, the best of the curve's top k on
        the validation slews (selection.py)."""
        assert self.kept  # run() evaluates at least once before it returns False
        snapshot, scores = validate(self.kept, self.spec)
        extra: dict = {"best_env_steps": snapshot["env_steps"]}
        if scores:
            extra["selection"] = scores
        return actor_from_state(self.spec, snapshot["actor"]), snapshot["grid"], extra

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        keep_buffer = self.buffer.size * (self.buffer.nbytes / self.buffer.capacity) <= CHECKPOINT_BUFFER_LIMIT_BYTES
        return {
            "env_steps": self.env_steps,
            "update_credit": self.update_credit,
            "next_eval": self.next_eval,
            "next_ckpt": self.next_ckpt,
            "curve": copy.deepcopy(self.curve),
            "kept": self.kept,
            "agent": to_cpu(self.agent.state_dict()),
            "env": to_cpu(self.env.state_dict()),
            "buffer": to_cpu(self.buffer.state_dict()) if keep_buffer else None,
            "gen": self.gen.get_state(),
            "cpu_gen": self.cpu_gen.get_state(),
            "rng": self.rng.bit_generator.state,
            "explore_design": self.explore_design.cpu().clone(),
        }

    def load_state_dict(self, d: dict) -> None:
        self.env_steps, self.update_credit = d["env_steps"], d["update_credit"]
        self.next_eval, self.next_ckpt = d["next_eval"], d["next_ckpt"]
        self.curve = list(d["curve"])
        # Checkpoints from before `select_top_k` hold one snapshot, "best".
        self.kept = list(d["kept"]) if "kept" in d else [d["best"]] if d.get("best") else []
        for s in self.kept:  # the grid is a list in a checkpoint's bytes (weights_only loading)
            s["grid"] = np.asarray(s["grid"], dtype=np.int64)
        self.agent.load_state_dict(to_device(d["agent"], self.device))
        self.env.load_state_dict(to_device(d["env"], self.device))
        if d["buffer"] is not None:
            self.buffer.load_state_dict(to_device(d["buffer"], self.device))
        else:  # too big to checkpoint: refill before learning again
            self.t = self.t.model_copy(update={"learning_starts": self.env_steps + self.t.learning_starts})
        self.gen.set_state(d["gen"])
        self.cpu_gen.set_state(d["cpu_gen"])
        self.rng.bit_generator.state = d["rng"]
        # Checkpoints of the removed `exploration_noise_min` hold each episode's noise draw,
        # "noise_u": not read (a run that set the key does not load, docs/lab/2026-12-05-unused-knobs-removed.md).
        self.explore_design.copy_(d["explore_design"])
        self.env.randomising = self.randomising()
