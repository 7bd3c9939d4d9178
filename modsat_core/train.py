"""Training runs: TD3 co-design, TD3 control of a fixed design, and the GA baseline.

``train(spec, ...)`` is the one entry point (the worker and the CLI call it); its contract
is written in docs/train-interface.md. It does no I/O and never reads the clock: progress,
checkpoints and stopping go through the three callbacks, and the finished run's files come
back as bytes from :meth:`RunResult.artifacts`.

Environment steps are MDP steps: a design step and a control step count one each, per
parallel episode. Learning-curve and final evaluations are not counted. Steps are taken in
batches of ``training.num_envs``; a run never exceeds its budget (it stops before a batch
that would), so it may end up to ``num_envs - 1`` steps short of it.
"""

from __future__ import annotations

import copy
import io
import math
import pickle
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from .codesign_env import Compact, CoDesignEnv, effective_invalid_penalty, observe_compact
from .evaluate import monte_carlo
from .features import N_FEATURES, CellObs
from .morphology import ACTUATOR, EMPTY, is_valid, mass_properties
from .networks import finish, make_actor, make_critic
from .pd import PDController
from .policy import PolicyController, design_with, export_torchscript
from .slew import Design
from .spec import JobSpec, UnrunnableSpec
from .td3 import TD3, ReplayBuffer, TD3Config

ProgressFn = Callable[[dict], None]
CheckpointFn = Callable[[dict], None]
StopFn = Callable[[], bool]

#: Final-evaluation tolerances reported beside the mission's own.
REPORT_TOLERANCES_DEG = (0.25, 1.0)
#: The replay buffer goes into checkpoints only up to this size (bigger buffers are refilled
#: after a resume: learning restarts after ``learning_starts`` fresh transitions).
CHECKPOINT_BUFFER_LIMIT_BYTES = 256 * 2**20
CHECKPOINT_VERSION = 2
#: Version 2: the network is named in the file (``per-module`` or ``set``), 53 features.
POLICY_VERSION = 2


def resolve_device(name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise UnrunnableSpec("training.device is 'cuda' but torch sees no GPU on this machine; "
                             "use 'auto' or 'cpu'")
    return name


def checkpoint_to_bytes(ckpt: dict) -> bytes:
    buf = io.BytesIO()
    torch.save(ckpt, buf)
    return buf.getvalue()


def checkpoint_from_bytes(data: bytes) -> dict:
    return torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)


def _noop(*_a, **_k):
    return None


def _never() -> bool:
    return False


# ----------------------------------------------------------------------------- buffer


def replay_fields(N: int) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """The compact transition layout: two compact states, the action, reward, terminal, and
    ``done`` (the episode ended there, also by its time limit: where n-step returns stop)."""
    C = N**3
    state = {"grid": ((C,), torch.uint8), "design_step": ((), torch.int16), "q_BN": ((4,), torch.float32),
             "q_TN": ((4,), torch.float32), "omega_B": ((3,), torch.float32), "h_cells": ((C, 3), torch.float16)}
    fields = {f"obs_{k}": v for k, v in state.items()}
    fields.update({f"next_{k}": v for k, v in state.items()})
    fields.update({"action": ((C, 3), torch.float16), "reward": ((), torch.float32), "terminal": ((), torch.bool),
                   "done": ((), torch.bool)})
    return fields


def replay_buffer_bytes(N: int, capacity: int) -> int:
    """Memory of a full replay buffer of ``capacity`` transitions on an N^3 grid."""
    return capacity * sum(
        math.prod(shape) * torch.empty((), dtype=dt).element_size() for shape, dt in replay_fields(N).values()
    )


# ----------------------------------------------------------------------------- result


@dataclass
class RunResult:
    """What :func:`train` returns. ``artifacts()`` is empty for a stopped run."""

    stopped: bool
    env_steps: int
    curve: list[dict] = field(default_factory=list)
    files: dict[str, bytes] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)

    def artifacts(self) -> dict[str, bytes]:
        return dict(self.files)


# ----------------------------------------------------------------------------- policy file


def new_actor(spec: JobSpec) -> torch.nn.Module:
    """The co-design actor of a spec (``training.network``, ``training.hidden_sizes``)."""
    return make_actor(spec.training.network, N_FEATURES, list(spec.training.hidden_sizes))


def actor_from_state(spec: JobSpec, state: dict) -> torch.nn.Module:
    """A CPU actor in eval mode holding ``state`` (a state dict of :func:`new_actor`'s actor)."""
    actor = new_actor(spec)
    actor.load_state_dict(state)
    actor.eval()
    return actor


def policy_bytes(actor: torch.nn.Module, grid: np.ndarray | None, spec: JobSpec) -> bytes:
    buf = io.BytesIO()
    torch.save({
        "format": "modsat-policy", "version": POLICY_VERSION, "spec": spec.model_dump(mode="json"),
        "grid": None if grid is None else np.asarray(grid).tolist(), "network": spec.training.network,
        "hidden_sizes": list(spec.training.hidden_sizes), "n_features": N_FEATURES,
        "actor": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
    }, buf)
    return buf.getvalue()


def load_policy(data: bytes) -> tuple[torch.nn.Module, np.ndarray | None, JobSpec]:
    """Read ``policy.pt``: the actor (CPU, eval mode), its design grid and the run's spec.

    A policy file is downloaded and shared, so it is read with ``weights_only=True``: tensors
    and plain data only; a pickle that would build other objects (and could run code) is
    refused."""
    try:
        d = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise ValueError("not a modsat policy file: it holds objects other than tensors and plain data, which "
                         f"are not loaded (torch.load weights_only): {str(exc).splitlines()[-1][:200]}") from None
    if not isinstance(d, dict) or d.get("format") != "modsat-policy":
        raise ValueError("not a modsat policy file")
    if d.get("version") != POLICY_VERSION or d.get("n_features") != N_FEATURES:
        raise ValueError(f"policy file version {d.get('version')} ({d.get('n_features')} features) is from an "
                         f"older modsat; this one reads version {POLICY_VERSION} ({N_FEATURES} features): "
                         "train the run again")
    spec = JobSpec.model_validate(d["spec"])
    actor = actor_from_state(spec, d["actor"])
    grid = None if d["grid"] is None else np.asarray(d["grid"], dtype=np.int64)
    return actor, grid, spec


# ----------------------------------------------------------------------------- evaluation


def curve_seed(spec: JobSpec) -> int:
    """Seed of the learning-curve slews: distinct from the final evaluation's set."""
    return (spec.evaluation.seed + 7919) % (2**31)


def evaluate_design(actor: torch.nn.Module, grid: np.ndarray, spec: JobSpec, *, episodes: int, seed: int,
                    record: int = 0, dtype=torch.float32, device: str = "cpu"):
    """Monte-Carlo of the actor flying ``grid``; None if the grid is not a valid satellite."""
    if not is_valid(grid):
        return None
    return monte_carlo(Design.from_grid(grid, spec.modules), PolicyController(actor, grid, spec), spec.mission,
                       spec.modules, episodes=episodes, seed=seed, record=record, dtype=dtype, device=device)


def curve_point(actor: torch.nn.Module, grid: np.ndarray, spec: JobSpec, env_steps: int, updates: int,
                penalty: float) -> dict:
    mc = evaluate_design(actor, grid, spec, episodes=spec.training.eval_episodes, seed=curve_seed(spec))
    n_mod = int((np.asarray(grid) != EMPTY).sum())
    n_act = int((np.asarray(grid) == ACTUATOR).sum())
    point = {"env_steps": env_steps, "updates": updates, "valid": mc is not None, "modules": n_mod,
             "actuators": n_act}
    if mc is None:
        point.update({"mean_return": penalty, "success_rate": 0.0})
    else:
        s = mc.summary()
        point.update({k: s[k] for k in ("mean_return", "success_rate", "median_final_error_deg",
                                        "median_slew_time_ratio")})
    return point


def design_report(grid: np.ndarray, spec: JobSpec) -> dict:
    grid = np.asarray(grid)
    out = {"grid": grid.tolist(), "grid_size": int(grid.shape[0]), "valid": bool(is_valid(grid)),
           "modules": int((grid != EMPTY).sum()), "actuators": int((grid == ACTUATOR).sum()),
           "types": {"0": "empty", "1": "structure", "2": "actuator"}}
    if out["modules"]:
        mp = mass_properties(grid, spec.modules.module_mass_kg, spec.modules.module_size_m)
        out.update({"mass_kg": float(mp.mass_kg), "com_grid_m": np.asarray(mp.com_grid_m).tolist(),
                    "inertia_kgm2": np.asarray(mp.inertia_B_kgm2).tolist(),
                    "principal_inertia_kgm2": np.linalg.eigvalsh(mp.inertia_B_kgm2).tolist()})
    return out


def final_evaluation(actor: torch.nn.Module, grid: np.ndarray, spec: JobSpec, episodes: int | None = None) -> dict:
    """The policy and the PD baseline on the same design and the same seeded slews."""
    ev = spec.evaluation
    n = episodes or ev.episodes
    tols = tuple(sorted({*REPORT_TOLERANCES_DEG, spec.mission.tolerance_deg}))
    out = {"episodes": n, "seed": ev.seed, "design_valid": bool(is_valid(grid))}
    if not out["design_valid"]:
        pen = effective_invalid_penalty(spec)
        out["policy"] = {"summary": {"episodes": n, "success_rate": 0.0, "mean_return": pen, "std_return": 0.0},
                         "episodes": []}
        out["pd_baseline"] = None
        out["trajectories"] = {"policy": [], "pd_baseline": []}
        return out
    design = Design.from_grid(grid, spec.modules)
    kw = dict(episodes=n, seed=ev.seed, record=min(ev.trajectories, n), dtype=torch.float64)
    mc = monte_carlo(design, PolicyController(actor, grid, spec), spec.mission, spec.modules, **kw)
    pd = monte_carlo(design, PDController, spec.mission, spec.modules, **kw)
    out["policy"] = {"summary": mc.summary(tols), "episodes": mc.episodes}
    out["pd_baseline"] = {"summary": pd.summary(tols), "episodes": pd.episodes}
    out["trajectories"] = {"policy": mc.trajectories, "pd_baseline": pd.trajectories}
    return out


def curve_png(curve: list[dict], title: str) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=100)
    x = [p["env_steps"] for p in curve]
    ax1.plot(x, [p["mean_return"] for p in curve], marker="o", ms=3)
    ax1.set_xlabel("environment steps")
    ax1.set_ylabel("mean evaluation return")
    ax2.plot(x, [100 * p["success_rate"] for p in curve], marker="o", ms=3, color="tab:green")
    ax2.set_xlabel("environment steps")
    ax2.set_ylabel("success rate (%)")
    ax2.set_ylim(-5, 105)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def run_files(spec: JobSpec, curve: list[dict], actor: torch.nn.Module, grid: np.ndarray, extra: dict | None = None
              ) -> tuple[dict[str, bytes], dict]:
    """All output files of a finished run, and a short summary of its evaluation."""
    import json

    ev = final_evaluation(actor, grid, spec)
    traj = ev.pop("trajectories")
    title = f"{spec.name or spec.algorithm}: {spec.design.grid_size}^3, seed {spec.seed}"
    files = {
        "spec.json": spec.model_dump_json(indent=2).encode(),
        "curve.json": json.dumps({"algorithm": spec.algorithm, "points": curve, **(extra or {})}, indent=1).encode(),
        "curve.png": curve_png(curve, title),
        "design.json": json.dumps(design_report(grid, spec), indent=1).encode(),
        "evaluation.json": json.dumps(ev, indent=1).encode(),
        "trajectories.json": json.dumps(traj).encode(),
        "policy.pt": policy_bytes(actor, grid, spec),
    }
    if ev["design_valid"]:
        files["policy_export.pt"] = export_torchscript(actor, grid, spec)
    summary = {"policy": ev["policy"]["summary"],
               "pd_baseline": ev["pd_baseline"]["summary"] if ev["pd_baseline"] else None,
               "design": {k: v for k, v in design_report(grid, spec).items() if k != "grid"}}
    return files, summary


# ----------------------------------------------------------------------------- TD3 run


class TD3Run:
    """One TD3 training run on the batched MDP (co-design, or control of a fixed design)."""

    def __init__(self, spec: JobSpec, *, fixed_grid: np.ndarray | None = None, device: str = "cpu"):
        if fixed_grid is None and spec.algorithm == "td3-control":
            fixed_grid = np.asarray(spec.design.fixed_design)
        self.spec, self.t = spec, spec.training
        self.device = device
        self.fixed_grid = None if fixed_grid is None else np.asarray(fixed_grid, dtype=np.int64)
        self.env = CoDesignEnv(spec, self.t.num_envs, seed=spec.seed, fixed_grid=self.fixed_grid, device=device)
        torch.manual_seed(spec.seed)
        actor = new_actor(spec).to(device)
        critic = make_critic(self.t.network, N_FEATURES, list(self.t.hidden_sizes)).to(device)
        self.agent = TD3(actor, critic, TD3Config(
            gamma=self.t.gamma, tau=self.t.tau, policy_noise=self.t.policy_noise, noise_clip=self.t.noise_clip,
            policy_delay=self.t.policy_delay, actor_lr=self.t.actor_lr, critic_lr=self.t.critic_lr))
        capacity = min(self.t.buffer_size, max(self.t.total_env_steps, self.t.batch_size))
        self.buffer = ReplayBuffer(replay_fields(self.env.N), capacity, device=device)
        self.gen = torch.Generator(device=device).manual_seed(spec.seed)
        self.cpu_gen = torch.Generator().manual_seed(spec.seed + 1)
        self.rng = np.random.default_rng([spec.seed, 3])
        self.env_steps = 0
        self.update_credit = 0.0
        self.next_eval = self.t.eval_every_steps
        self.next_ckpt = self.t.checkpoint_every_steps
        self.curve: list[dict] = []
        self.best: dict | None = None  # {"mean_return", "actor", "grid", "env_steps"}
        self.recent: list[dict] = []  # finished training episodes since the last progress call
        self.last_info: dict = {}
        self.explore_design = torch.ones(self.env.B, dtype=torch.bool, device=device)

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
            swap = (torch.rand((B, C, 1), generator=self.gen, device=self.device) < p_swap)
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

        Drawn once per episode, when its design phase starts."""
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
        return design_with(self._eval_actor(), self.spec)

    def _cpu_actor(self) -> torch.nn.Module:
        a = copy.deepcopy(self.agent.actor).cpu()
        a.eval()
        return a

    def _eval_actor(self) -> torch.nn.Module:
        return self.agent.actor if self.device == "cpu" else self._cpu_actor()

    # ------------------------------------------------------------------ loop
    def run(self, on_progress: ProgressFn, on_checkpoint: CheckpointFn, should_stop: StopFn,
            budget: int | None = None) -> bool:
        """Train until the budget is spent; returns True if ``should_stop`` ended it early."""
        total = self.t.total_env_steps if budget is None else budget
        B = self.env.B
        N, D, rl = self.env.N, self.env.D, self.spec.mission.rate_limit_rad_s
        progress_every = max(B, total // 200)
        next_progress = (self.env_steps // progress_every + 1) * progress_every
        # Steps come in batches of B; a batch that would overrun the budget is not taken.
        while self.env_steps + B <= total:
            if should_stop():
                on_checkpoint(self.state_dict())
                return True
            obs_c = self.env.compact()
            obs = observe_compact(obs_c, N, D, rl)
            action = self._act(obs)
            st = self.env.step(action)
            self.buffer.add({**obs_c.as_dict("obs_"), **st.next_state.as_dict("next_"), "action": action,
                             "reward": st.reward, "terminal": st.terminal, "done": st.done})
            self.recent.extend(st.finished)
            self.env_steps += B
            if self.env_steps >= self.t.learning_starts and self.buffer.size >= self.t.batch_size:
                self.update_credit += B / self.t.train_frequency
                while self.update_credit >= 1.0:
                    self.update_credit -= 1.0
                    self._update()
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
        if self.best is None:  # a budget smaller than one batch: the untrained policy
            on_progress(self.progress(total, self.evaluate_now()))
        return False

    def _update(self) -> None:
        discount = None
        if self.t.n_step > 1:
            b, discount = self.buffer.sample_n_step(self.t.batch_size, self.t.n_step, self.env.B, self.t.gamma,
                                                    self.gen)
        else:
            b = self.buffer.sample(self.t.batch_size, self.gen)
        N, D, rl = self.env.N, self.env.D, self.spec.mission.rate_limit_rad_s
        obs = observe_compact(Compact.from_dict(b, "obs_"), N, D, rl)
        nxt = observe_compact(Compact.from_dict(b, "next_"), N, D, rl)
        action = b["action"].float()
        # Until design_learning_starts the design layers are held: the controller learns to fly
        # the design the policy starts from (and the explored ones near it) before it moves.
        actor_rows = ~obs.design if self.env_steps < self.t.design_learning_starts else None
        self.last_info = self.agent.update(obs, action, b["reward"], nxt, b["terminal"], self.gen, discount,
                                           actor_rows)

    def evaluate_now(self) -> dict:
        actor = self._eval_actor()
        grid = self.current_grid()
        point = curve_point(actor, grid, self.spec, self.env_steps, self.agent.updates, self.env.penalty)
        self.curve.append(point)
        if self.best is None or _rank(point) > _rank(self.best):
            self.best = {"mean_return": point["mean_return"], "success_rate": point["success_rate"],
                         "env_steps": self.env_steps, "grid": grid,
                         "actor": {k: v.detach().cpu().clone() for k, v in actor.state_dict().items()}}
        return point

    def progress(self, total: int, point: dict | None) -> dict:
        recent, self.recent = self.recent, []
        out = {"env_steps": self.env_steps, "total_env_steps": total, "updates": self.agent.updates,
               "phase": "training", "eval": point}
        if recent:
            out["train_episodes"] = len(recent)
            out["train_mean_return"] = float(np.mean([r["return"] for r in recent]))
            out["train_valid_rate"] = float(np.mean([r["valid"] for r in recent]))
            out["train_success_rate"] = float(np.mean([bool(r.get("success")) for r in recent]))
        for k in ("critic_loss", "actor_loss", "q"):
            if k in self.last_info:
                out[k] = self.last_info[k]
        return out

    def best_actor(self) -> tuple[torch.nn.Module, np.ndarray]:
        """The snapshot the final evaluation uses (best success rate on the curve, then best
        return), and its design."""
        return actor_from_state(self.spec, self.best["actor"]), self.best["grid"]

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        keep_buffer = self.buffer.size * (self.buffer.nbytes / self.buffer.capacity) <= CHECKPOINT_BUFFER_LIMIT_BYTES
        return {
            "env_steps": self.env_steps, "update_credit": self.update_credit, "next_eval": self.next_eval,
            "next_ckpt": self.next_ckpt, "curve": copy.deepcopy(self.curve), "best": self.best,
            "agent": _to_cpu(self.agent.state_dict()), "env": _to_cpu(self.env.state_dict()),
            "buffer": _to_cpu(self.buffer.state_dict()) if keep_buffer else None,
            "gen": self.gen.get_state(), "cpu_gen": self.cpu_gen.get_state(), "rng": self.rng.bit_generator.state,
            "explore_design": self.explore_design.cpu().clone(),
        }

    def load_state_dict(self, d: dict) -> None:
        self.env_steps, self.update_credit = d["env_steps"], d["update_credit"]
        self.next_eval, self.next_ckpt = d["next_eval"], d["next_ckpt"]
        self.curve, self.best = list(d["curve"]), d["best"]
        self.agent.load_state_dict(_to_device(d["agent"], self.device))
        self.env.load_state_dict(_to_device(d["env"], self.device))
        if d["buffer"] is not None:
            self.buffer.load_state_dict(_to_device(d["buffer"], self.device))
        else:  # too big to checkpoint: refill before learning again
            self.t = self.t.model_copy(update={"learning_starts": self.env_steps + self.t.learning_starts})
        self.gen.set_state(d["gen"])
        self.cpu_gen.set_state(d["cpu_gen"])
        self.rng.bit_generator.state = d["rng"]
        self.explore_design.copy_(d["explore_design"])


def _rank(point: dict) -> tuple[float, float]:
    """Snapshots are compared by success rate first, then by return (a policy that lands
    more slews beats one that collects more shaping reward without landing them)."""
    return point.get("success_rate", 0.0), point["mean_return"]


def _to_cpu(x):
    if isinstance(x, torch.Tensor):
        return x.detach().cpu()
    if isinstance(x, dict):
        return {k: _to_cpu(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_to_cpu(v) for v in x]
    return x


def _to_device(x, device):
    if isinstance(x, torch.Tensor):
        return x.to(device)
    if isinstance(x, dict):
        return {k: _to_device(v, device) for k, v in x.items()}
    if isinstance(x, list):
        return [_to_device(v, device) for v in x]
    return x


# ----------------------------------------------------------------------------- entry point


def train(
    spec: JobSpec,
    *,
    on_progress: ProgressFn | None = None,
    on_checkpoint: CheckpointFn | None = None,
    should_stop: StopFn | None = None,
    checkpoint: dict | None = None,
) -> RunResult:
    """Run ``spec`` to the end of its env-step budget (or until ``should_stop``).

    See docs/train-interface.md. Resuming from ``checkpoint`` continues the same run.
    """
    on_progress, on_checkpoint, should_stop = on_progress or _noop, on_checkpoint or _noop, should_stop or _never
    if checkpoint is not None and checkpoint.get("version") != CHECKPOINT_VERSION:
        raise ValueError("checkpoint from an incompatible modsat version")
    if spec.algorithm == "ga":
        from .ga import GARun

        return GARun(spec, device=resolve_device(spec.training.device)).train(
            on_progress, on_checkpoint, should_stop, checkpoint)
    device = resolve_device(spec.training.device)
    run = TD3Run(spec, device=device)
    if checkpoint is not None:
        run.load_state_dict(_to_device(checkpoint["run"], device))

    def wrap(state: dict) -> None:
        on_checkpoint({"version": CHECKPOINT_VERSION, "algorithm": spec.algorithm, "env_steps": state["env_steps"],
                       "run": state})

    stopped = run.run(on_progress, wrap, should_stop)
    if stopped:
        return RunResult(stopped=True, env_steps=run.env_steps, curve=run.curve)
    on_progress({"env_steps": run.env_steps, "total_env_steps": spec.training.total_env_steps,
                 "updates": run.agent.updates, "phase": "evaluating", "eval": None})
    actor, grid = run.best_actor()
    files, summary = run_files(spec, run.curve, actor, grid, {"best_env_steps": run.best["env_steps"]})
    return RunResult(stopped=False, env_steps=run.env_steps, curve=run.curve, files=files, summary=summary)
