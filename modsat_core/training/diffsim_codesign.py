"""`diffsim-codesign`: a design distribution learned by policy gradient, flown by a design-conditioned
first-order controller trained on its designs.

The design is a distribution over grids: independent per-cell type logits (empty, structure,
actuator), payload cells fixed to structure (``objective.payload_cells``; with none, the centre cell
is an actuator, the seed the paper's designs grow from). A drawn grid becomes a satellite by keeping
what is face-connected to those fixed cells; it is valid if it then has a wheel unit.

The run alternates:

- ``diffsim.design_every`` controller updates as `diffsim-control`'s (:class:`DiffsimRun`), the
  controller design-conditioned (``diffsim.design_pool`` > 0's inputs) and every training slew
  flying one of the distribution's latest draws (or its mode);
- one design update: ``design_batch`` grids drawn, each flown by the controller on the same
  ``design_slews`` slews (the training physics, no gradient), each scored by the objective
  (:func:`objective_s`, lower is better; an invalid grid scores worse than any valid one), and the
  logits moved by the score-function gradient (REINFORCE with the batch's mean as baseline,
  advantages normalised) with Adam (``design_lr``).

With ``diffsim.design_gradient`` `relaxed` the logits move instead by the gradient of a relaxed
grid's objective backpropagated through the simulator (:meth:`DiffsimCodesignRun.relaxed_objective`);
the draws still feed the controller's training and the kept-design candidates. Measured on
`diffsim-3x3x3` seeds 0-2 and `diffsim-5x5x5` (docs/diffsim.md, "Score function or relaxed grid"):
the relaxed gradient keeps better designs at 2-4x the wall time, but its distribution's mode carries
fewer wheel units than the designs it prices (the relaxed optimum is fractional; on 5x5x5 none), so
the score function, whose distribution converges to a valid design, stays the default.

The kept design: the distribution's mode and the run's three best draws are flown on the
validation slews (``evaluation.episodes`` of them, the mission's physics) and the best objective
wins; the final evaluation flies it with the controller at the end of training, beside PD. A run that
trains for the flight conditions (``randomise``) keeps a flight-ready design: the candidates, best
objective first, fly the validation slews under each of ``evaluation.conditions`` too, and the first
that lands :data:`FLIGHT_READY_SHARE` of them under every one is kept (where none does, the one whose
worst condition is best; the evaluation then flags it). The validation slews are not the final
evaluation's, so that evaluation still measures a design it was not chosen on. The paper's initial
design (:func:`initial_design`, the full cube) flies in the candidates' batch, on the same slews by
the same controller, never a candidate: the comparison the kept design is read against (curve.json's
``initial_design``).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor

from modsat_core.agent.diffsim_policy import DiffsimController
from modsat_core.agent.policy_file import actor_from_state
from modsat_core.evaluation.monte_carlo import monte_carlo, monte_carlo_conditions
from modsat_core.grid import ACTUATOR, EMPTY, STRUCTURE, flood_fill
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.morphology import mass_properties_of_occupancy
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import DesignSpace, JobSpec, ModuleCatalog
from modsat_core.spec.objective import Objective
from modsat_core.spec.parts import design_mass_kg
from modsat_core.training.diffsim import DiffsimRun, _smooth_norm, training_mission

#: Candidates for the kept design besides the distribution's mode: the run's best draws.
TOP_DRAWS = 3
#: A design is flight-ready when its controller lands at least this share of the slews under each
#: flight condition (the trade-off's front asks the same of its points).
FLIGHT_READY_SHARE = 0.99
#: Width, in natural-log units, of the relaxed objective's soft tolerance step (within a factor
#: e**0.5 of the tolerance the step is between 27 % and 73 % of the way).
RELAXED_SOFTNESS = 0.5


def objective_s(
    episodes: list[dict],
    grid: np.ndarray,
    objective: Objective,
    episode_s: float,
    catalog: ModuleCatalog | None = None,
) -> float:
    """A design's objective (seconds, lower is better; the module docstring of
    :mod:`modsat_core.spec.objective`) from its flown ``episodes`` (monte_carlo rows); the mass price
    weighs the design with ``catalog`` (the spec's ``modules``)."""
    times = [e["settling_time_s"] if e["success"] else episode_s for e in episodes]
    g = np.asarray(grid)
    modules, wheels = int((g != EMPTY).sum()), int((g >= ACTUATOR).sum())
    out = float(np.mean(times)) + objective.module_price_s * modules + objective.wheel_price_s * wheels
    if objective.mass_price_s_per_kg and catalog is not None:
        out += objective.mass_price_s_per_kg * design_mass_kg(g, catalog)
    return out


def initial_logits(shape: tuple[int, ...], empty_prior: float | None) -> Tensor:
    """Per-cell type logits (..., T), float64, that draw a cell empty with probability ``empty_prior``
    and every other type equally often (None: every type equally, zeros)."""
    logits = torch.zeros(shape, dtype=torch.float64)
    if empty_prior is not None:
        T = shape[-1]
        logits[..., EMPTY] = math.log(empty_prior * (T - 1) / (1.0 - empty_prior))
    return logits.requires_grad_(True)


def first_designs(drawn: list[np.ndarray], fixed: np.ndarray, types: np.ndarray) -> list[np.ndarray]:
    """A design learner's first training designs: its draws that are valid (a wheel unit), else a design
    with a wheel unit in every free cell. The simulator's wheel-unit slots grow with the designs it flies."""
    flyable = [g for g in drawn if (g >= ACTUATOR).any()]
    if flyable:
        return flyable
    every = np.full(fixed.shape, ACTUATOR, dtype=np.int64)
    every[fixed] = types[fixed]
    return [every]


def fixed_cells(
    design_space: DesignSpace, objective: Objective, catalog: ModuleCatalog | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The cells the design learner never changes, (N, N, N) bool, and their types (int64): the payload's
    cells (the objective's, or the parts catalog's ``catalog.payload``) as structure, else the grid's
    centre as an actuator."""
    N = design_space.grid_size
    mask = np.zeros((N, N, N), dtype=bool)
    types = np.zeros((N, N, N), dtype=np.int64)
    own = catalog.payload.cells if catalog is not None and catalog.payload is not None else []
    payload = list(objective.payload_cells) or [(c[0], c[1], c[2]) for c in own]
    if payload:
        for c in payload:
            mask[c], types[c] = True, STRUCTURE
    else:
        c = (N // 2,) * 3
        mask[c], types[c] = True, ACTUATOR
    return mask, types


def cell_types(spec: JobSpec) -> int:
    """How many parts a design cell chooses among: empty, structure and each wheel type of the catalog
    (one wheel unit type without one)."""
    return ACTUATOR + (len(spec.modules.wheels) if spec.modules.wheels else 1)


def initial_design(design_space: DesignSpace, objective: Objective, catalog: ModuleCatalog | None = None) -> np.ndarray:
    """The paper's initial design, (N, N, N) int64: the full cube of structure modules whose centre
    module is a wheel unit (a parts catalog's first), the fixed cells as :func:`fixed_cells` gives them
    (the payload as structure). Without a wheel unit where a payload covers the centre."""
    N = design_space.grid_size
    cube = np.full((N, N, N), STRUCTURE, dtype=np.int64)
    cube[(N // 2,) * 3] = ACTUATOR
    fixed, types = fixed_cells(design_space, objective, catalog)
    return np.where(fixed, types, cube).astype(np.int64)


def satellites(raw: np.ndarray, fixed: np.ndarray, types: np.ndarray) -> np.ndarray:
    """(M, N, N, N) drawn grids -> the satellites they make: the fixed cells given their types
    (:func:`fixed_cells`), then the modules face-connected to them."""
    raw = np.where(fixed, types, raw)
    filled = raw != EMPTY
    reached = flood_fill(np.broadcast_to(fixed, raw.shape) & filled, filled)
    return np.where(reached, raw, EMPTY).astype(np.int64)


def fly_grids(
    spec: JobSpec, controller: Any, grids: list[np.ndarray], slews: int, seed: int, exact: bool
) -> list[list[dict]]:
    """Each grid flown by ``controller`` on the same ``slews`` slews of ``seed``: its monte_carlo rows.
    ``controller``: a design-conditioned :class:`~modsat_core.agent.diffsim_policy.DiffsimPolicy`, or a
    controller class such as :class:`~modsat_core.sim.pd.PDController`. The training physics in float32
    (compiled with ``diffsim.compiled``), or the mission's in float64 when ``exact`` (compiled with
    ``evaluation.compiled``). A grid without a
    wheel unit gets no rows."""
    from modsat_core.agent.diffsim_policy import DiffsimPolicy
    from modsat_core.agent.policy import controller_for

    mission = spec.mission if exact else training_mission(spec.mission, spec.diffsim.substeps)
    valid = [i for i, g in enumerate(grids) if (g >= ACTUATOR).any()]
    out: list[list[dict]] = [[] for _ in grids]
    if not valid:
        return out
    designs = [Design.from_grid(grids[i], spec.modules) for i in valid for _ in range(slews)]
    if isinstance(controller, DiffsimPolicy):
        controller = controller_for(controller, grids[valid[0]], spec)
    with torch.no_grad():
        mc = monte_carlo(
            designs,
            controller,
            mission,
            spec.modules,
            episodes=len(designs),
            seed=seed,
            dtype=torch.float64 if exact else torch.float32,
            slews=slews,
            # the training's design scores (diffsim.compiled), or the validation's (evaluation.compiled)
            compiled=spec.evaluation.compiled if exact else spec.diffsim.compiled,
        )
    for j, i in enumerate(valid):
        out[i] = mc.episodes[j * slews : (j + 1) * slews]
    return out


def score_designs(
    spec: JobSpec, controller: Any, grids: list[np.ndarray], slews: int, seed: int, exact: bool
) -> list[float]:
    """The objective of each grid flown on the same ``slews`` slews of ``seed`` by ``controller``
    (:func:`fly_grids`). A grid without a wheel unit scores worse than any valid design."""
    obj = spec.objective
    episode_s = spec.mission.episode_steps * spec.mission.control_dt_s
    worst = episode_s + spec.design.grid_size**3 * (obj.module_price_s + obj.wheel_price_s)
    flown = fly_grids(spec, controller, grids, slews, seed, exact)
    return [
        objective_s(eps, g, obj, episode_s, spec.modules) if eps else worst for eps, g in zip(flown, grids, strict=True)
    ]


def draw_grids(
    logits: Tensor, M: int, rng: np.random.Generator, fixed: np.ndarray, types: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``M`` satellites from per-cell type ``logits`` (N^3, T) and the raw grids they were drawn as."""
    N = fixed.shape[0]
    p = torch.softmax(logits.detach(), dim=-1).numpy()
    u = rng.random((M, N**3, 1))
    raw = (u > np.cumsum(p, axis=-1)[None, :, :-1]).sum(-1).reshape(M, N, N, N)
    raw = np.where(fixed, types, raw)
    return satellites(raw, fixed, types), raw


def mode_grid(logits: Tensor, fixed: np.ndarray, types: np.ndarray) -> np.ndarray:
    """The satellite of each cell's most probable type."""
    N = fixed.shape[0]
    raw = torch.softmax(logits.detach(), dim=-1).numpy().argmax(-1).reshape(1, N, N, N)
    return satellites(raw, fixed, types)[0]


def grid_log_prob(logits: Tensor, raw: np.ndarray, fixed: np.ndarray) -> Tensor:
    """(M,) log-probability of each raw grid under ``logits`` (N^3, T), the fixed cells excluded."""
    logp = torch.log_softmax(logits, dim=-1)
    idx = torch.as_tensor(raw.reshape(len(raw), -1))
    free = torch.as_tensor(~fixed.reshape(-1), dtype=torch.float64)
    return (logp.gather(1, idx.T).T * free).sum(-1)


def design_state(run: Any, best: Any) -> dict:
    """A design learner's checkpoint: its logits, optimiser, draws' stream, records, best draws (as
    given, grids as lists), the designs training flies and the curve's design."""
    return {
        "logits": run.logits.detach().clone(),
        "design_opt": run.design_opt.state_dict(),
        "design_rng": run.design_rng.bit_generator.state,
        "records": copy.deepcopy(run.records),
        "best": best,
        "pool": [d.grid.tolist() for d in run.pool],
        "active": list(run.active),
        "grid": run.grid.tolist(),
    }


def load_design_state(run: Any, c: dict) -> None:
    """:func:`design_state` back into ``run`` (its best draws and its grid are the caller's)."""
    with torch.no_grad():
        run.logits.copy_(c["logits"])
    run.design_opt.load_state_dict(c["design_opt"])
    run.design_rng.bit_generator.state = c["design_rng"]
    run.records = list(c["records"])
    run.pool = [Design.from_grid(np.asarray(g, dtype=np.int64), run.spec.modules) for g in c["pool"]]
    run.active = (int(c["active"][0]), int(c["active"][1]))


def best_from_state(best: list[dict]) -> list[dict]:
    return [{"grid": np.asarray(b["grid"], dtype=np.int64), "objective_s": b["objective_s"]} for b in best]


def best_to_state(best: list[dict]) -> list[dict]:
    return [{"grid": b["grid"].tolist(), "objective_s": b["objective_s"]} for b in best]


class DiffsimCodesignRun(DiffsimRun):
    """One `diffsim-codesign` run (see the module docstring)."""

    def __init__(self, spec: JobSpec, device: str = "cpu"):
        N = spec.design.grid_size
        self.fixed, self.fixed_types = fixed_cells(spec.design, spec.objective, spec.modules)
        # a cell's types: empty, structure, and each wheel unit type of the parts catalog
        types = cell_types(spec)
        self.logits = initial_logits((N**3, types), spec.diffsim.design_empty_prior)
        self.design_opt = torch.optim.Adam([self.logits], lr=spec.diffsim.design_lr)
        self.design_rng = np.random.default_rng([spec.seed, 5])
        self.records: list[dict] = []  # one per design update
        self.best: list[dict] = []  # the run's best draws, best first: {"grid", "objective_s"}
        self.on_stage: Callable[[str], None] = lambda _what: None  # what the final choice is flying
        super().__init__(spec, device)

    # ------------------------------------------------------------------ the distribution
    def initial_pool(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """The mode and a first batch of draws, those that are valid (:func:`first_designs`)."""
        pool = first_designs([self.mode(), *self.draw(self.d.design_batch)[0]], self.fixed, self.fixed_types)
        return pool[0], pool

    def probabilities(self) -> np.ndarray:
        return torch.softmax(self.logits.detach(), dim=-1).numpy()

    def draw(self, M: int) -> tuple[np.ndarray, np.ndarray]:
        """``M`` satellites from the distribution and the raw grids they were drawn as."""
        return draw_grids(self.logits, M, self.design_rng, self.fixed, self.fixed_types)

    def mode(self) -> np.ndarray:
        return mode_grid(self.logits, self.fixed, self.fixed_types)

    def log_prob(self, raw: np.ndarray) -> torch.Tensor:
        """(M,) log-probability of each raw grid under the logits (the fixed cells excluded)."""
        return grid_log_prob(self.logits, raw, self.fixed)

    # ------------------------------------------------------------------ scoring
    def score(self, grids: list[np.ndarray], slews: int, seed: int, exact: bool) -> list[float]:
        """The objective of each grid flown by the controller (:func:`score_designs`)."""
        policy = copy.deepcopy(self.policy).cpu().eval()
        return score_designs(self.spec, policy.double() if exact else policy, grids, slews, seed, exact)

    def relaxed_objective(self, seed: int) -> Tensor:
        """The relaxed grid's objective, differentiable in the logits (``design_gradient`` `relaxed`).

        Each free cell holds ``p_structure + p_actuator`` of a module's mass and ``p_actuator`` of a
        wheel unit (a weighted slot of the simulator, its torque and momentum scaled by it); the
        fixed cells are what they are. Connectivity is not relaxed: a probable cell counts even
        where the cells that would join it to the payload are improbable. The controller (its
        weights held) flies this satellite on ``design_slews`` slews for the mission's episode in
        the training physics, float64, with the gradient through every step; the objective is the
        mean soft time out of tolerance (each step's ``dt (1 - s(phi) s(w))``, with
        ``s(x) = sigmoid(-ln(x / tol) / RELAXED_SOFTNESS)`` for the angle and the rate against their
        tolerances) plus the prices of the expected modules and wheel units."""
        spec, m = self.spec, self.spec.modules
        obj, mission = spec.objective, spec.mission
        p = torch.softmax(self.logits, dim=-1)
        fixed = torch.as_tensor(self.fixed.reshape(-1))
        ftypes = torch.as_tensor(self.fixed_types.reshape(-1))
        occ = torch.where(fixed, (ftypes != EMPTY).double(), p[:, STRUCTURE] + p[:, ACTUATOR])
        wheel = torch.where(fixed, (ftypes >= ACTUATOR).double(), p[:, ACTUATOR])
        _, _, I_B = mass_properties_of_occupancy(occ.unsqueeze(0), m.module_mass_kg, m.module_size_m)
        S = self.d.design_slews
        sim = SlewSim(
            I_B.expand(S, 3, 3),
            wheel.unsqueeze(0).expand(S, -1),
            training_mission(mission, self.d.substeps),
            m,
            dtype=torch.float64,
        )
        rng = np.random.default_rng([seed, 9])
        sim.reset(list(range(S)), [draw_episode(rng, mission) for _ in range(S)])
        policy = copy.deepcopy(self.policy).cpu().double().eval().requires_grad_(False)
        controller = DiffsimController(policy, mission.rate_limit_rad_s, self.d.base)
        log_tol = math.log(math.radians(mission.tolerance_deg))
        log_rate_tol = math.log(mission.rate_tolerance_rad_s)
        out = torch.zeros((), dtype=torch.float64)
        for _ in range(mission.episode_steps):
            sim.step(controller(sim))
            q = sim.error_quaternion()
            phi = 2.0 * torch.atan2(_smooth_norm(q[:, 1:], 1e-24), q[:, 0])
            w = _smooth_norm(sim.state.omega_B, 1e-24)
            inside = torch.sigmoid(-(torch.log(phi) - log_tol) / RELAXED_SOFTNESS) * torch.sigmoid(
                -(torch.log(w) - log_rate_tol) / RELAXED_SOFTNESS
            )
            out = out + (1.0 - inside).mean() * mission.control_dt_s
        return out + obj.module_price_s * occ.sum() + obj.wheel_price_s * wheel.sum()

    def design_update(self) -> None:
        """Draw, score, step the logits, refresh the designs training flies (module docstring)."""
        M = self.d.design_batch
        grids, raw = self.draw(M)
        seed = int(self.design_rng.integers(2**31))
        J = np.asarray(self.score(list(grids), self.d.design_slews, seed, exact=False))
        self.design_opt.zero_grad(set_to_none=True)
        relaxed: float | None = None
        if self.d.design_gradient == "relaxed":
            loss = self.relaxed_objective(seed)
            relaxed = float(loss.detach())
        else:
            adv = torch.as_tensor((J - J.mean()) / (J.std() + 1e-8))
            loss = (adv * self.log_prob(raw)).mean()  # descending it lowers the expected objective
        loss.backward()
        self.design_opt.step()
        for g, j in sorted(zip(list(grids), J.tolist(), strict=True), key=lambda x: x[1])[:TOP_DRAWS]:
            if (g >= ACTUATOR).any() and not any(np.array_equal(g, b["grid"]) for b in self.best):
                self.best.append({"grid": g, "objective_s": j})
        self.best = sorted(self.best, key=lambda b: b["objective_s"])[:TOP_DRAWS]
        mode = self.mode()
        if (mode >= ACTUATOR).any():
            self.grid = mode
        else:  # the mode has no wheel yet: the curve flies the run's best draw
            self.grid = self.best[0]["grid"]
        fresh = [g for g in [self.grid, *grids] if (g >= ACTUATOR).any()]
        start = len(self.pool)
        self.pool += [Design.from_grid(g, self.spec.modules) for g in fresh]
        self.active = (start, len(self.pool))
        p = self.probabilities()
        self.records.append(
            {
                "updates": self.updates,
                "env_steps": self.env_steps,
                "mean_objective_s": float(J.mean()),
                "best_objective_s": float(J.min()),
                "valid_draws": int(sum((g >= ACTUATOR).any() for g in grids)),
                **({} if relaxed is None else {"relaxed_objective_s": relaxed}),
                "entropy_nats": float(-(p * np.log(p + 1e-12)).sum(-1)[~self.fixed.reshape(-1)].mean()),
                "mode": mode.tolist(),
                "modules": int((mode != EMPTY).sum()),
                "actuators": int((mode >= ACTUATOR).sum()),
            }
        )

    def update(self) -> dict[str, float]:
        out = super().update()
        if self.updates % self.d.design_every == 0:
            self.design_update()
        return out

    # ------------------------------------------------------------------ the end
    def chosen(self) -> tuple[torch.nn.Module, np.ndarray, dict]:
        """The controller at the end of training and the kept design: the mode or one of the run's
        best draws, whichever scores best on the validation slews. The initial design flies in the
        same batch (never a candidate): its objective is the record's ``initial_design``."""
        candidates = [self.mode(), *[b["grid"] for b in self.best]]
        unique: list[np.ndarray] = []
        for g in candidates:
            if (g >= ACTUATOR).any() and not any(np.array_equal(g, u) for u in unique):
                unique.append(g)
        if not unique:  # a run too short for a design update, its mode without a wheel unit: the curve's design
            unique.append(self.grid)
        ev = self.spec.evaluation
        self.on_stage(f"the kept design: {len(unique)} candidates on {ev.episodes} validation slews")
        cube = initial_design(self.spec.design, self.spec.objective, self.spec.modules)
        flyable = bool((cube >= ACTUATOR).any())
        same = [i for i, g in enumerate(unique) if np.array_equal(g, cube)]
        scores = self.score([*unique, *([cube] if flyable and not same else [])], ev.episodes, ev.seed + 1, exact=True)
        scores, cube_score = scores[: len(unique)], scores[same[0] if same else -1]
        selection = [
            {"grid": g.tolist(), "objective_s": s, "mode": i == 0 and np.array_equal(g, candidates[0])}
            for i, (g, s) in enumerate(zip(unique, scores, strict=True))
        ]
        actor = actor_from_state(self.spec, {k: v.cpu() for k, v in self.policy.state_dict().items()})
        best = self.flight_ready_choice(actor, unique, scores, selection)
        extra: dict[str, Any] = {"designs": self.records, "selection": selection}
        if flyable:
            extra["initial_design"] = {"grid": cube.tolist(), "objective_s": cube_score}
        return actor, unique[best], extra

    def flight_ready_choice(
        self, actor: torch.nn.Module, grids: list[np.ndarray], scores: list[float], selection: list[dict]
    ) -> int:
        """Index of the kept design among ``grids`` (validation ``scores``): the best objective, or, for a
        run trained for the flight conditions, the best flight-ready one (the module docstring). Each
        candidate flown under the conditions gets its success per condition in ``selection``."""
        order = sorted(range(len(grids)), key=lambda i: scores[i])
        spec, ev = self.spec, self.spec.evaluation
        if not (spec.randomise.active and ev.conditions):
            return order[0]
        from modsat_core.agent.policy import controller_for

        worst: dict[int, float] = {}
        for n, i in enumerate(order, start=1):
            self.on_stage(
                f"the kept design: candidate {n} of {len(order)} under {len(ev.conditions)} flight conditions"
            )
            with torch.no_grad():
                res = monte_carlo_conditions(
                    Design.from_grid(grids[i], spec.modules),
                    controller_for(actor, grids[i], spec),
                    spec.mission,
                    spec.modules,
                    ev.conditions,
                    episodes=ev.episodes,
                    seed=ev.seed + 1,
                    dtype=torch.float64,
                    compiled=ev.compiled,
                )
            conds = {c.name: sum(bool(e["success"]) for e in res[c.name].episodes) / ev.episodes for c in ev.conditions}
            selection[i]["conditions"] = conds
            worst[i] = min(conds.values())
            selection[i]["flight_ready"] = worst[i] >= FLIGHT_READY_SHARE
            if selection[i]["flight_ready"]:
                return i
        return max(order, key=lambda i: (worst[i], -scores[i]))

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        d = super().state_dict()
        d["codesign"] = design_state(self, best_to_state(self.best))
        return d

    def load_state_dict(self, d: dict) -> None:
        c = d["codesign"]
        load_design_state(self, c)
        self.best = best_from_state(c["best"])
        super().load_state_dict(d)
        self.grid = np.asarray(c["grid"], dtype=np.int64)
