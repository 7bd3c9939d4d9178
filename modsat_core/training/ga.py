"""The genetic-algorithm baseline: designs evolved, each flown by its own controller (TD3's, or
the first-order learner's with ``ga.inner`` `diffsim`).

It follows Evolution Gym's GA (Bhatia et al. 2021), the paper's baseline:

* generation 0 is ``population_size`` random valid designs (every cell empty, structure
  or actuator with equal probability; invalid draws are drawn again);
* each new design gets a fresh controller trained for ``steps_per_design`` env steps on that
  fixed design by the inner learner (the last one gets what is left of the budget; with
  `diffsim`, a `diffsim-control` run of that budget); its fitness is the
  mean return of the controller's best learning-curve evaluation;
* between generations the best ``max(2, ceil(P * f))`` designs survive (capped at P - 1
  so every generation brings something new), where the survivor fraction ``f`` moves
  linearly from ``survivor_start`` to ``survivor_end`` with the share of the budget
  spent; survivors keep their fitness, the rest of the population is children of random
  survivors, each cell mutated with probability ``mutation_rate`` to another type;
* a child that is invalid, or a design already evaluated, is drawn again: every
  evaluated design is valid and unique.

The run ends when the env-step budget ``training.total_env_steps`` is spent (less than
one batch of ``num_envs`` steps left); steps of the curve evaluations are not counted (as
for the RL run). The budget is never exceeded.
"""

from __future__ import annotations

import math

import numpy as np

from modsat_core.agent.policy import controller_for
from modsat_core.agent.policy_file import actor_from_state
from modsat_core.artefacts import CurvePoint, ProgressRecord
from modsat_core.evaluation.run_files import run_files
from modsat_core.grid import is_valid, random_design
from modsat_core.spec.jobspec import GA, JobSpec, Training, is_diffsim
from modsat_core.training.checkpoint import CHECKPOINT_VERSION
from modsat_core.training.diffsim import DiffsimRun
from modsat_core.training.diffsim_codesign import fixed_cells, satellites, score_designs
from modsat_core.training.result import RunResult
from modsat_core.training.td3_trainer import TD3Run

MAX_DRAWS = 100_000


def survivor_count(ga: GA, training: Training, used: int) -> tuple[int, float]:
    """Survivors after ``used`` env steps of the budget (``training.total_env_steps``): (count,
    scheduled fraction)."""
    P = ga.population_size
    share = min(1.0, used / training.total_env_steps)
    frac = ga.survivor_start + (ga.survivor_end - ga.survivor_start) * share
    return min(max(2, math.ceil(P * frac)), P - 1), frac


def mutate(rng: np.random.Generator, grid: np.ndarray, rate: float) -> np.ndarray:
    """Each cell, with probability ``rate``, becomes one of the two other types."""
    flip = rng.random(grid.shape) < rate
    shift = rng.integers(1, 3, size=grid.shape)
    return np.where(flip, (grid + shift) % 3, grid).astype(np.int64)


def draw_unique(rng: np.random.Generator, make, seen: set[bytes]) -> np.ndarray:
    for _ in range(MAX_DRAWS):
        g = make()
        if is_valid(g) and g.tobytes() not in seen:
            seen.add(g.tobytes())
            return g
    raise RuntimeError(f"GA: no new valid design in {MAX_DRAWS} draws; the design space is exhausted")


class GARun:
    def __init__(self, spec: JobSpec, *, device: str = "cpu"):
        self.spec, self.device = spec, device
        self.N = spec.design.grid_size
        self.rng = np.random.default_rng([spec.seed, 4])
        self.used = 0
        self.generation = 0
        self.records: list[dict] = []  # every evaluated design, in order
        self.population: list[int] = []  # indices into records: the current generation
        self.pending: list[np.ndarray] = []  # designs of this generation still to evaluate
        self.generations: list[dict] = []  # survivor schedule, one row per new generation
        self.seen: set[bytes] = set()
        self.best_actor: dict | None = None
        self.inner_ckpt: dict | None = None
        self.curve: list[dict] = []

    @property
    def step_unit(self) -> int:
        """The fewest env steps an inner run takes: one batch of TD3's environments, or one update
        of the first-order learner."""
        if is_diffsim(self.spec):
            return self.spec.diffsim.batch_size * self.spec.diffsim.window_steps
        return self.spec.training.num_envs

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict:
        return {
            "used": self.used,
            "generation": self.generation,
            "records": self.records,
            "population": self.population,
            "pending": [g.tolist() for g in self.pending],
            "generations": self.generations,
            "seen": sorted(self.seen),
            "best_actor": self.best_actor,
            "inner": self.inner_ckpt,
            "curve": self.curve,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, d: dict) -> None:
        self.used, self.generation = d["used"], d["generation"]
        self.records, self.population = list(d["records"]), list(d["population"])
        self.pending = [np.asarray(g, dtype=np.int64) for g in d["pending"]]
        self.generations, self.seen = list(d["generations"]), set(d["seen"])
        self.best_actor, self.inner_ckpt, self.curve = d["best_actor"], d["inner"], list(d["curve"])
        self.rng.bit_generator.state = d["rng"]

    # ------------------------------------------------------------------ evolution
    def _first_generation(self) -> None:
        P = self.spec.ga.population_size

        def make() -> np.ndarray:
            return self.with_payload(random_design(self.rng, self.N))

        self.pending = [draw_unique(self.rng, make, self.seen) for _ in range(P)]

    def with_payload(self, grid: np.ndarray) -> np.ndarray:
        """``grid`` with the spec's payload cells (if any) and only what is connected to them."""
        if not self.spec.objective.payload_cells:
            return grid
        fixed, types = fixed_cells(self.spec.design, self.spec.objective, self.spec.modules)
        return satellites(grid[None], fixed, types)[0]

    def _next_generation(self) -> None:
        n_surv, frac = survivor_count(self.spec.ga, self.spec.training, self.used)
        ranked = sorted(self.population, key=lambda i: self.records[i]["fitness"], reverse=True)
        survivors = ranked[:n_surv]
        self.generation += 1
        P = self.spec.ga.population_size
        rate = self.spec.ga.mutation_rate

        def child() -> np.ndarray:
            parent = self.records[survivors[int(self.rng.integers(len(survivors)))]]["grid"]
            return self.with_payload(mutate(self.rng, np.asarray(parent, dtype=np.int64), rate))

        self.pending = [draw_unique(self.rng, child, self.seen) for _ in range(P - n_surv)]
        self.population = list(survivors)
        self.generations.append(
            {
                "generation": self.generation,
                "env_steps": self.used,
                "budget_share": min(1.0, self.used / self.spec.training.total_env_steps),
                "survivor_fraction": frac,
                "survivors": n_surv,
                "children": P - n_surv,
            }
        )

    def _evaluate_pending(self, on_progress, on_checkpoint, should_stop) -> bool:
        """Train a controller for each pending design in turn; True if stopped."""
        total = self.spec.training.total_env_steps
        while self.pending and total - self.used >= self.step_unit:
            grid = self.pending[0]
            budget = min(self.spec.ga.steps_per_design, total - self.used)
            seed = (self.spec.seed * 7919 + len(self.records)) % (2**31)
            # The GA reads the inner run's curve best (`kept[0]`), which `select_top_k` does not
            # change: one snapshot, not k copies in every inner checkpoint.
            one = self.spec.training.model_copy(update={"select_top_k": 1})
            run: TD3Run | DiffsimRun
            if is_diffsim(self.spec):  # its own run on this design, the budget its total
                one = one.model_copy(update={"total_env_steps": budget})
                design = self.spec.design.model_copy(update={"fixed_design": grid.tolist()})
                update = {"seed": seed, "training": one, "design": design, "algorithm": "diffsim-control"}
                inner_spec = self.spec.model_copy(update=update)
                run = DiffsimRun(inner_spec, device=self.device)
            else:
                inner_spec = self.spec.model_copy(update={"seed": seed, "training": one})
                run = TD3Run(inner_spec, fixed_grid=grid, device=self.device)
            if self.inner_ckpt is not None:
                run.load_state_dict(self.inner_ckpt)
            offset = self.used

            def progress(p: dict, _o=offset, _g=self.generation) -> None:
                on_progress(
                    ProgressRecord.model_validate(
                        {
                            **p,
                            "env_steps": _o + p["env_steps"],
                            "total_env_steps": total,
                            "phase": f"ga generation {_g}, design {len(self.records) + 1}",
                            "eval": None
                            if p.get("eval") is None
                            else {**p["eval"], "env_steps": _o + p["eval"]["env_steps"]},
                        }
                    ).to_dict()
                )

            def checkpoint(inner: dict) -> None:
                self.inner_ckpt = inner
                on_checkpoint(self.state_dict())

            stopped = (
                run.run(progress, checkpoint, should_stop)
                if isinstance(run, DiffsimRun)
                else run.run(progress, checkpoint, should_stop, budget=budget)
            )
            if stopped:
                return True
            self.inner_ckpt = None
            assert run.kept  # a finished run has evaluated at least once
            fitness = run.kept[0]["mean_return"]
            objective: dict = {}
            if self.spec.ga.fitness == "objective":  # the design's price, flown by its own controller
                controller = controller_for(actor_from_state(inner_spec, run.kept[0]["actor"]), grid, inner_spec)
                slews = self.spec.diffsim.design_slews
                objective["objective_s"] = score_designs(self.spec, controller, [grid], slews, seed, exact=False)[0]
                fitness = -objective["objective_s"]
            self.used += run.env_steps
            self.records.append(
                {
                    **objective,
                    "grid": grid.tolist(),
                    "fitness": fitness,
                    "generation": self.generation,
                    "env_steps": run.env_steps,
                    "seed": seed,
                    "success_rate": max(p["success_rate"] for p in run.curve),
                }
            )
            self.population.append(len(self.records) - 1)
            if self.best_actor is None or fitness > self.best_actor["fitness"]:
                self.best_actor = {
                    "fitness": fitness,
                    "grid": grid.tolist(),
                    "actor": run.kept[0]["actor"],
                    "record": len(self.records) - 1,
                }
            self.pending.pop(0)
            self.curve.append(
                CurvePoint(
                    env_steps=self.used,
                    mean_return=self.best_actor["fitness"],
                    success_rate=self.records[self.best_actor["record"]]["success_rate"],
                    design_return=fitness,
                    generation=self.generation,
                ).to_dict()
            )
            on_checkpoint(self.state_dict())
        return False

    def train(self, on_progress, on_checkpoint, should_stop, checkpoint: dict | None):
        def wrap(state: dict) -> None:
            on_checkpoint({"version": CHECKPOINT_VERSION, "algorithm": "ga", "env_steps": state["used"], "run": state})

        if checkpoint is not None:
            self.load_state_dict(checkpoint["run"])
        elif not self.records and not self.pending:
            self._first_generation()
        total = self.spec.training.total_env_steps
        while True:
            if self._evaluate_pending(on_progress, wrap, should_stop):
                return RunResult(stopped=True, env_steps=self.used, curve=self.curve)
            if total - self.used < self.step_unit:  # not one more batch of steps
                break
            self._next_generation()
        on_progress(
            ProgressRecord(
                env_steps=self.used, total_env_steps=total, updates=0, phase="evaluating", eval=None
            ).to_dict()
        )
        assert self.best_actor is not None  # at least one design was evaluated
        actor = actor_from_state(self.spec, self.best_actor["actor"])
        grid = np.asarray(self.best_actor["grid"], dtype=np.int64)
        extra = {"designs": self.records, "generations": self.generations}
        files, summary = run_files(self.spec, self.curve, actor, grid, extra)
        summary["designs_evaluated"] = len(self.records)
        return RunResult(stopped=False, env_steps=self.used, curve=self.curve, files=files, summary=summary)
