"""The trade-off: `diffsim-codesign` with ``objective.trade_off_prices_s_per_kg`` returns the Pareto front of
flown designs over total mass and median settling time, each point flown by the run's one flight-ready,
design-conditioned controller, and names the lightest design that meets ``requirements``
(docs/requirements.md).

The method: one design distribution per mass price ``lambda_l`` of the list, all sharing the controller.
Each distribution is :class:`~modsat_core.training.diffsim_codesign.DiffsimCodesignRun`'s (per-cell type
logits over empty, structure and every wheel type of the parts catalog; the payload fixed; a drawn grid
is what stays face-connected to it), scored by the objective with its own price: mean settling time (a
failed slew counts the episode) plus the module and wheel prices plus ``lambda_l`` times the design's
mass from the catalog. At each design update every distribution draws ``design_batch / L`` grids (at least
4); all are flown together on the same ``design_slews`` slews; each distribution takes its REINFORCE step
on its own draws. The controller trains on the draws of all of them (under ``randomise``: the flight
conditions), so that it flies the whole range of masses and wheel sets the front spans. A cheap price
pulls its distribution to heavy, well-actuated satellites, a dear one to the lightest that still land.

The run keeps an archive of its draws: those that landed every design slew, reduced after each design
update to the non-dominated set over (mass, median settling); it fills the gaps between the prices' optima
and costs no flight (the bench gives NSGA-II as many design evaluations).

After training, a local search (``diffsim.front_search_designs``; :mod:`~modsat_core.training.front_search`)
flies neighbours of the candidates' non-dominated ones; up to :data:`SEARCH_CANDIDATES` of its
non-dominated points join the candidates.

At the end the candidates (each distribution's mode and its best draws, up to
:data:`ARCHIVE_CANDIDATES` archive points spread over its mass range, and the search's) fly the validation slews
(``evaluation.episodes``, the mission's physics, float64). The front is their non-dominated set over
(mass, median settling time) among those that land every slew and are flight-ready (moocore): the
non-dominated points fly every flight condition of ``evaluation.conditions``; a point that lands less than
:data:`FLIGHT_READY_SHARE` of the slews under one (of those the requirements judge) is dropped and the
front taken again, until every point of it is flight-ready (where none is, the nominal front, each point
saying so). Each point carries its success per condition, ``flight_ready`` and the requirements' verdict;
the candidates dropped stay in ``selection`` with theirs. The run's kept design is
the lightest front point that meets the requirements, else the front point of least objective at the
middle price (the final evaluation says then that no front point meets them, with every reason).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from modsat_core.agent.policy import controller_for
from modsat_core.agent.policy_file import actor_from_state
from modsat_core.evaluation.monte_carlo import monte_carlo_conditions
from modsat_core.grid import ACTUATOR, EMPTY
from modsat_core.sim.slew import Design
from modsat_core.spec.evaluation import Condition
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.limits import TRADE_OFF_EXTRA_CANDIDATES
from modsat_core.spec.parts import design_mass_kg, design_power_W
from modsat_core.spec.requirements import judged, requirement_verdict
from modsat_core.training.diffsim import DiffsimRun
from modsat_core.training.diffsim_codesign import (
    TOP_DRAWS,
    best_from_state,
    best_to_state,
    cell_types,
    design_state,
    draw_grids,
    first_designs,
    fixed_cells,
    fly_grids,
    grid_log_prob,
    initial_logits,
    load_design_state,
    mode_grid,
)
from modsat_core.training.front_search import local_search, mean_time_s, nondominated

#: Fewest draws a distribution takes at a design update.
MIN_DRAWS = 4
#: A front point is flight-ready when it lands at least this share of the slews nominally and under each
#: flight condition (those the requirements judge, where there are requirements).
FLIGHT_READY_SHARE = 0.99
#: Most points of the run's archive (the non-dominated draws) that join the final candidates, spread
#: over its range of mass (admission's estimates count them: modsat_core.spec.limits).
ARCHIVE_CANDIDATES = 16
#: The local search's non-dominated points that join the candidates, at most (spread over its mass range).
SEARCH_CANDIDATES = TRADE_OFF_EXTRA_CANDIDATES - ARCHIVE_CANDIDATES


def median_settling_s(episodes: list[dict], episode_s: float) -> float:
    """Median settling time, a failed slew counting the whole episode."""
    if not episodes:
        return episode_s
    return float(np.median([e["settling_time_s"] if e["success"] else episode_s for e in episodes]))


def hypervolume(points: np.ndarray, ref: tuple[float, float]) -> float:
    """The area (kg s) the points (P, 2) dominate up to ``ref`` (moocore's hypervolume; minimised)."""
    import moocore

    pts = np.asarray([p for p in np.asarray(points, dtype=np.float64) if p[0] < ref[0] and p[1] < ref[1]])
    if len(pts) == 0:
        return 0.0
    return float(moocore.hypervolume(pts, ref=np.asarray(ref, dtype=np.float64)))


def reference_point(spec: JobSpec) -> tuple[float, float]:
    """The hypervolume's reference: the heaviest satellite the grid holds (every free cell the heaviest
    wheel unit, the payload) and the whole episode."""
    N = spec.design.grid_size
    fixed, types = fixed_cells(spec.design, spec.objective, spec.modules)
    n_types = len(spec.modules.wheels) if spec.modules.wheels else 1
    heaviest = max(
        design_mass_kg(np.where(fixed, types, np.full((N,) * 3, ACTUATOR + k)), spec.modules) for k in range(n_types)
    )
    return float(heaviest), spec.mission.episode_steps * spec.mission.control_dt_s


def point_record(spec: JobSpec, grid: np.ndarray, episodes: list[dict], episode_s: float) -> dict[str, Any]:
    """A flown design's figures: its parts, mass, power, median settling time and success."""
    g = np.asarray(grid)
    n_types = len(spec.modules.wheels) if spec.modules.wheels else 1
    names = [w.name for w in spec.modules.wheels] if spec.modules.wheels else ["wheel-unit"]
    return {
        "grid": g.tolist(),
        "modules": int((g != EMPTY).sum()),
        "wheel_units": {names[k]: int((g == ACTUATOR + k).sum()) for k in range(n_types)},
        "mass_kg": design_mass_kg(g, spec.modules),
        "power_W": design_power_W(g, spec.modules),
        "median_settling_s": median_settling_s(episodes, episode_s),
        "success": sum(bool(e["success"]) for e in episodes) / max(1, len(episodes)),
    }


class ParetoRun(DiffsimRun):
    """One trade-off run (the module docstring)."""

    def __init__(self, spec: JobSpec, device: str = "cpu"):
        N = spec.design.grid_size
        self.prices = list(spec.objective.trade_off_prices_s_per_kg)
        L = len(self.prices)
        self.fixed, self.fixed_types = fixed_cells(spec.design, spec.objective, spec.modules)
        types = cell_types(spec)
        self.logits = initial_logits((L, N**3, types), spec.diffsim.design_empty_prior)
        self.design_opt = torch.optim.Adam([self.logits], lr=spec.diffsim.design_lr)
        self.design_rng = np.random.default_rng([spec.seed, 5])
        self.records: list[dict] = []
        self.best: list[list[dict]] = [[] for _ in range(L)]  # per price: {"grid", "objective_s"}, best first
        self.front: list[dict] = []
        #: The non-dominated draws of the whole run over (mass, median settling on their design slews),
        #: among those that landed every slew: {"grid", "mass_kg", "settling_s", "price"}, lightest first.
        self.archive: list[dict] = []
        #: What the local search flew (set by :meth:`searched`; None without one).
        self.search: dict[str, int] | None = None
        #: Told what the front's evaluation flies next (train() reports it as the evaluation's stage).
        self.on_stage: Callable[[str], None] = lambda _what: None
        super().__init__(spec, device)

    # ------------------------------------------------------------------ the distributions
    def draw(self, M: int, l: int) -> tuple[np.ndarray, np.ndarray]:
        return draw_grids(self.logits[l], M, self.design_rng, self.fixed, self.fixed_types)

    def mode(self, l: int) -> np.ndarray:
        return mode_grid(self.logits[l], self.fixed, self.fixed_types)

    def log_prob(self, raw: np.ndarray, l: int) -> torch.Tensor:
        return grid_log_prob(self.logits[l], raw, self.fixed)

    @property
    def draws_each(self) -> int:
        return max(MIN_DRAWS, self.d.design_batch // len(self.prices))

    def initial_pool(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """Every distribution's first draws that are valid (:func:`first_designs`)."""
        drawn = [g for l in range(len(self.prices)) for g in self.draw(self.draws_each, l)[0]]
        pool = first_designs(drawn, self.fixed, self.fixed_types)
        return pool[0], pool

    # ------------------------------------------------------------------ one design update
    def objective(self, time_s: float, grid: np.ndarray, price: float) -> float:
        obj = self.spec.objective
        g = np.asarray(grid)
        modules, wheels = int((g != EMPTY).sum()), int((g >= ACTUATOR).sum())
        return (
            time_s
            + obj.module_price_s * modules
            + obj.wheel_price_s * wheels
            + price * design_mass_kg(g, self.spec.modules)
        )

    def design_update(self) -> None:
        L, M = len(self.prices), self.draws_each
        draws = [self.draw(M, l) for l in range(L)]
        grids = [g for grids, _ in draws for g in grids]
        seed = int(self.design_rng.integers(2**31))
        policy = copy.deepcopy(self.policy).cpu().eval()
        episode_s = self.spec.mission.episode_steps * self.spec.mission.control_dt_s
        flown = fly_grids(self.spec, policy, grids, self.d.design_slews, seed, exact=False)
        times = [mean_time_s(e, episode_s) for e in flown]
        self.update_archive(grids, flown, [self.prices[i // M] for i in range(len(grids))], episode_s)
        self.design_opt.zero_grad(set_to_none=True)
        loss = torch.zeros((), dtype=torch.float64)
        record: dict[str, Any] = {"updates": self.updates, "env_steps": self.env_steps, "prices": []}
        for l, (lg, raw) in enumerate(draws):
            J = np.asarray([self.objective(times[l * M + i], g, self.prices[l]) for i, g in enumerate(lg)])
            adv = torch.as_tensor((J - J.mean()) / (J.std() + 1e-8))
            loss = loss + (adv * self.log_prob(raw, l)).mean()
            for g, j in sorted(zip(list(lg), J.tolist(), strict=True), key=lambda x: x[1])[:TOP_DRAWS]:
                if (g >= ACTUATOR).any() and not any(np.array_equal(g, b["grid"]) for b in self.best[l]):
                    self.best[l].append({"grid": g, "objective_s": j})
            self.best[l] = sorted(self.best[l], key=lambda b: b["objective_s"])[:TOP_DRAWS]
            mode = self.mode(l)
            record["prices"].append(
                {
                    "price_s_per_kg": self.prices[l],
                    "mean_objective_s": float(J.mean()),
                    "best_objective_s": float(J.min()),
                    "mode_mass_kg": design_mass_kg(mode, self.spec.modules),
                    "mode_wheel_units": int((mode >= ACTUATOR).sum()),
                }
            )
        loss.backward()
        self.design_opt.step()
        middle = self.mode(L // 2)
        if (middle >= ACTUATOR).any():  # the curve flies the middle price's mode, else a best draw
            self.grid = middle
        else:
            self.grid = next((b[0]["grid"] for b in [self.best[L // 2], *self.best] if b), self.grid)
        fresh = [g for g in [self.grid, *grids] if (g >= ACTUATOR).any()]
        start = len(self.pool)
        self.pool += [Design.from_grid(g, self.spec.modules) for g in fresh]
        self.active = (start, len(self.pool))
        self.records.append(record)

    def update_archive(
        self, grids: list[np.ndarray], flown: list[list[dict]], prices: list[float], episode_s: float
    ) -> None:
        """Add the draws that landed every slew to the archive and keep its non-dominated set."""
        pts = list(self.archive)
        for g, eps, price in zip(grids, flown, prices, strict=True):
            if eps and all(e["success"] for e in eps) and not any(np.array_equal(g, p["grid"]) for p in pts):
                pts.append(
                    {
                        "grid": np.asarray(g, dtype=np.int64),
                        "mass_kg": design_mass_kg(g, self.spec.modules),
                        "settling_s": median_settling_s(eps, episode_s),
                        "price": price,
                    }
                )
        keep = nondominated(np.asarray([[p["mass_kg"], p["settling_s"]] for p in pts]))
        self.archive = sorted([p for p, k in zip(pts, keep, strict=True) if k], key=lambda p: p["mass_kg"])

    def update(self) -> dict[str, float]:
        out = super().update()
        if self.updates % self.d.design_every == 0:
            self.design_update()
        return out

    # ------------------------------------------------------------------ the front
    def candidates(self) -> list[tuple[np.ndarray, float]]:
        """Each distribution's mode and best draws, then up to :data:`ARCHIVE_CANDIDATES` points of the
        archive spread over its mass range, once each, with the price they came from."""
        picked = self.archive
        if len(picked) > ARCHIVE_CANDIDATES:
            idx = np.unique(np.round(np.linspace(0, len(picked) - 1, ARCHIVE_CANDIDATES)).astype(int))
            picked = [picked[i] for i in idx]
        out: list[tuple[np.ndarray, float]] = []
        found = [
            (g, price)
            for l, price in enumerate(self.prices)
            for g in [self.mode(l), *[b["grid"] for b in self.best[l]]]
        ]
        for g, price in found + [(p["grid"], p["price"]) for p in picked]:
            if (g >= ACTUATOR).any() and not any(np.array_equal(g, u) for u, _ in out):
                out.append((g, price))
        return out

    def trade_off(self, policy: torch.nn.Module) -> tuple[list[dict], list[dict]]:
        """Every candidate flown on the validation slews, and the front: the non-dominated ones that land
        every slew, each flown under every flight condition with its requirements' verdict."""
        spec, ev = self.spec, self.spec.evaluation
        episode_s = spec.mission.episode_steps * spec.mission.control_dt_s
        cands = self.candidates() or [(self.grid, self.prices[len(self.prices) // 2])]
        if spec.diffsim.front_search_designs:
            cands += self.searched(policy, cands)
        pol = copy.deepcopy(policy).cpu().double().eval()
        self.on_stage(f"the trade-off: {len(cands)} candidate designs on {ev.episodes} validation slews")
        flown = fly_grids(spec, pol, [g for g, _ in cands], ev.episodes, ev.seed + 1, exact=True)
        records = []
        for (g, price), episodes in zip(cands, flown, strict=True):
            r = point_record(spec, g, episodes, episode_s)
            r["price_s_per_kg"] = price
            r["objective_s"] = self.objective(mean_time_s(episodes, episode_s), g, price)
            r["_episodes"] = episodes
            records.append(r)
        landed = [r for r in records if r["success"] >= 1.0] or records
        # The front of flight-ready designs: fly the non-dominated set's points under every condition, drop
        # those that are not flight-ready, and take the front again, until every point of it is.
        pool = list(landed)
        while True:
            front = self.flown_front(pool, pol)
            if all(r["flight_ready"] for r in front):
                break
            pool = [r for r in pool if r.get("flight_ready") is not False]
            if not pool:  # no candidate is flight-ready: the nominal front, each point saying so
                front = self.flown_front(landed, pol)
                break
        for r in records:
            r.pop("_episodes")
        return records, front

    def searched(self, policy: torch.nn.Module, cands: list[tuple[np.ndarray, float]]) -> list[tuple[Any, float]]:
        """The local search's non-dominated points that are not candidates yet (at most
        :data:`SEARCH_CANDIDATES`, spread over their mass range), each with its starting candidate's price
        (:func:`~modsat_core.training.front_search.local_search`); ``self.search`` says what it flew."""
        budget = self.spec.diffsim.front_search_designs
        slews = self.d.design_slews

        def told(flown: int, budget: int) -> None:
            self.on_stage(f"the trade-off: local search, {flown} of {budget} designs flown on {slews} slews each")

        pol = copy.deepcopy(policy).cpu().float().eval()
        found, flown = local_search(self.spec, pol, [g for g, _ in cands], budget, told)
        new = [p for p in found if not any(np.array_equal(p["grid"], g) for g, _ in cands)]
        if len(new) > SEARCH_CANDIDATES:
            idx = np.unique(np.round(np.linspace(0, len(new) - 1, SEARCH_CANDIDATES)).astype(int))
            new = [new[i] for i in idx]
        self.search = {"designs_flown": flown, "slews": slews, "front": len(found), "new_candidates": len(new)}
        return [(p["grid"], cands[p["start"]][1]) for p in new]

    def flown_front(self, pool: list[dict[str, Any]], pol: torch.nn.Module) -> list[dict[str, Any]]:
        """The non-dominated records of ``pool`` over (mass, median settling), lightest first, each flown
        under the conditions (:meth:`fly_conditions`) unless it already was."""
        pts = np.asarray([[r["mass_kg"], r["median_settling_s"]] for r in pool])
        front = sorted([r for r, k in zip(pool, nondominated(pts), strict=True) if k], key=lambda r: r["mass_kg"])
        for r in front:
            if "conditions" not in r:
                n = len(self.spec.evaluation.conditions)
                self.on_stage(f"the trade-off: front design of {r['mass_kg']:.2f} kg under {n} flight conditions")
                self.fly_conditions(r, pol)
        return front

    def fly_conditions(self, r: dict[str, Any], pol: torch.nn.Module) -> None:
        """A candidate's flight under every condition of ``evaluation.conditions`` (success per
        condition), whether it is flight-ready (at least :data:`FLIGHT_READY_SHARE` under each judged
        one) and its requirements' verdict; written into the record ``r``."""
        spec, ev = self.spec, self.spec.evaluation
        grid = np.asarray(r["grid"], dtype=np.int64)
        flights: list[tuple[Condition, list[dict]]] = []
        if ev.conditions:
            design = Design.from_grid(grid, spec.modules)
            with torch.no_grad():
                res = monte_carlo_conditions(
                    design,
                    controller_for(pol, grid, spec),
                    spec.mission,
                    spec.modules,
                    ev.conditions,
                    episodes=ev.episodes,
                    seed=ev.seed,
                    dtype=torch.float64,
                    compiled=ev.compiled,
                )
            flights = [(c, res[c.name].episodes) for c in ev.conditions]
        conds = {c.name: sum(bool(e["success"]) for e in eps) / len(eps) for c, eps in flights}
        counted = [
            c.name for c, _ in flights if spec.requirements is None or judged(c, spec.requirements, spec.mission)
        ]
        ready = r["success"] >= FLIGHT_READY_SHARE and all(conds[n] >= FLIGHT_READY_SHARE for n in counted)
        r["conditions"], r["flight_ready"] = conds, bool(ready)
        if spec.requirements is not None:
            v = requirement_verdict(
                spec.requirements, spec.mission, r["mass_kg"], r["power_W"], r["_episodes"], flights
            )
            r["meets"], r["reasons"] = v["meets"], v["reasons"]

    def chosen(self) -> tuple[torch.nn.Module, np.ndarray, dict]:
        """The controller at the end of training and the kept design (the module docstring)."""
        records, front = self.trade_off(self.policy)
        meeting = [r for r in front if r.get("meets")]
        if meeting:
            kept = min(meeting, key=lambda r: r["mass_kg"])
        else:
            middle = self.prices[len(self.prices) // 2]
            kept = min(front, key=lambda r: self.objective(r["median_settling_s"], np.asarray(r["grid"]), middle))
        self.front = front
        ref = reference_point(self.spec)
        extra: dict[str, Any] = {
            "designs": self.records,
            "selection": records,
            "front": front,
            "front_reference": {"mass_kg": ref[0], "settling_s": ref[1]},
            "front_hypervolume": hypervolume(np.asarray([[r["mass_kg"], r["median_settling_s"]] for r in front]), ref),
            "kept": {"grid": kept["grid"], "meets_requirements": bool(kept.get("meets", False))},
        }
        if self.search is not None:
            extra["front_search"] = self.search
        actor = actor_from_state(self.spec, {k: v.cpu() for k, v in self.policy.state_dict().items()})
        return actor, np.asarray(kept["grid"], dtype=np.int64), extra

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict:
        d = super().state_dict()
        d["pareto"] = design_state(self, [best_to_state(b) for b in self.best])
        d["pareto"]["archive"] = [{**p, "grid": p["grid"].tolist()} for p in self.archive]
        return d

    def load_state_dict(self, d: dict) -> None:
        c = d["pareto"]
        load_design_state(self, c)
        self.best = [best_from_state(b) for b in c["best"]]
        # checkpoints written before the archive have none
        self.archive = [{**p, "grid": np.asarray(p["grid"], dtype=np.int64)} for p in c.get("archive", [])]
        super().load_state_dict(d)
        self.grid = np.asarray(c["grid"], dtype=np.int64)
