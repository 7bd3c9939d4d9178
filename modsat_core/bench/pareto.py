"""``modsat bench pareto``: the trade-off a design review looks at, from three searches flown by one
controller and the paper's GA with a controller per design (docs/requirements.md).

For each seed, one trade-off run of a preset (`diffsim-codesign` with ``objective.trade_off_prices_s_per_kg``,
e.g. `trade-off-3x3x3`), timed from its start to its final evaluation (``train_s``). Its controller, at the
end of training, then flies three sets of designs on the same ``slews`` bench slews (a seed of their own,
float64, the mission's physics):

- ``codesign``: the run's front (its candidates' non-dominated set, chosen on the validation slews);
- ``nsga2``: the front of NSGA-II (pymoo) searching the same design space (each free cell empty, structure
  or a wheel unit of any catalog type; the payload kept) with the same controller as its evaluator on the
  training physics and ``design_slews`` slews, for as many design evaluations as the run made (its draws
  and its local search's flights);
- ``random``: the non-dominated set of ``designs`` random valid designs of that space.

Then the paper's method on the same problem (``ga_inner``, left out with ``ga=False``): the GA with a
controller per design (NSGA-II's selection, generations of ``GA_POPULATION``), each design it draws
trained alone by the first-order learner for ``GA_UPDATES`` updates as the preset trains (flight
conditions included), as many updates in all as the co-design run's controller trained; every design it
trained is flown by its own controller on the same bench slews.

Every front is the non-dominated set over (mass kg, median settling s) of the designs that land every
bench slew (a failed slew counts the episode's length in the median). Each row gives its points (mass,
median settling, power, success nominally and, for the co-design front, under each flight condition from
the run; whether it meets the requirements), its hypervolume against the stated reference point (the
heaviest satellite the grid holds, the whole episode), and how many of its points beat a co-design front
point by more than 2 % in both mass and settling time. One torch thread. The output is a JSON object.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from modsat_core.agent.policy_file import load_policy
from modsat_core.bench.learners import _cpu_model, timed_train
from modsat_core.grid import ACTUATOR
from modsat_core.spec.jobspec import JobSpec, parse_spec
from modsat_core.spec.presets import get_preset
from modsat_core.training.diffsim_codesign import cell_types, fixed_cells, fly_grids, satellites
from modsat_core.training.diffsim_pareto import (
    hypervolume,
    mean_time_s,
    nondominated,
    point_record,
    reference_point,
)

#: A point beats another when it is better in both mass and settling by more than this fraction.
MARGIN = 0.02
#: NSGA-II's population.
POPULATION = 32


def random_designs(spec: JobSpec, n: int, seed: int) -> list[np.ndarray]:
    """``n`` valid satellites of the uniform per-cell distribution over every part, the payload kept."""
    fixed, types = fixed_cells(spec.design, spec.objective, spec.modules)
    rng = np.random.default_rng([seed, 7])
    N, T = spec.design.grid_size, cell_types(spec)
    out: list[np.ndarray] = []
    while len(out) < n:
        g = satellites(rng.integers(0, T, size=(1, N, N, N)), fixed, types)[0]
        if (g >= ACTUATOR).any():
            out.append(g)
    return out


def nsga2_search(
    spec: JobSpec,
    score: Callable[[list[np.ndarray]], np.ndarray],
    generations: int,
    seed: int,
    population: int = POPULATION,
) -> list[np.ndarray]:
    """NSGA-II (pymoo) over the design space (each free cell empty, structure or a wheel unit of any
    catalog type; the payload kept) for ``generations`` generations of ``population``, each generation's
    designs scored by ``score`` (grids -> (G, 2) mass kg and settling s, lower better): the final
    non-dominated designs that carry a wheel unit."""
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.core.problem import Problem
    from pymoo.operators.crossover.sbx import SBX
    from pymoo.operators.mutation.pm import PM
    from pymoo.operators.repair.rounding import RoundingRepair
    from pymoo.operators.sampling.rnd import IntegerRandomSampling
    from pymoo.optimize import minimize

    fixed, types = fixed_cells(spec.design, spec.objective, spec.modules)
    N, T = spec.design.grid_size, cell_types(spec)
    free = np.flatnonzero(~fixed.reshape(-1))

    def grids_of(X: np.ndarray) -> list[np.ndarray]:
        raw = np.zeros((len(X), N**3), dtype=np.int64)
        raw[:, free] = np.clip(np.rint(X), 0, T - 1).astype(np.int64)
        return list(satellites(raw.reshape(-1, N, N, N), fixed, types))

    class Designs(Problem):
        def __init__(self) -> None:
            super().__init__(n_var=len(free), n_obj=2, xl=0, xu=T - 1, vtype=int)

        def _evaluate(self, X: np.ndarray, out: dict, *args: Any, **kwargs: Any) -> None:
            out["F"] = score(grids_of(X))

    algorithm = NSGA2(
        pop_size=population,
        sampling=IntegerRandomSampling(),
        crossover=SBX(prob=0.9, eta=15, vtype=float, repair=RoundingRepair()),
        mutation=PM(eta=20, vtype=float, repair=RoundingRepair()),
        eliminate_duplicates=True,
    )
    res = minimize(Designs(), algorithm, ("n_gen", max(1, generations)), seed=seed, verbose=False)
    X = np.atleast_2d(res.X)
    return [g for g in grids_of(X) if (g >= ACTUATOR).any()]


def scores(spec: JobSpec, grids: list[np.ndarray], flown: list[list[dict]]) -> np.ndarray:
    """(G, 2): each design's mass (twice the heaviest satellite if it flew nothing: no wheel unit) and
    mean settling time (a failed slew counts the episode), NSGA-II's objectives."""
    episode_s = spec.mission.episode_steps * spec.mission.control_dt_s
    heavy = reference_point(spec)[0]
    return np.asarray(
        [
            [point_record(spec, g, e, episode_s)["mass_kg"] if e else 2 * heavy, mean_time_s(e, episode_s)]
            for g, e in zip(grids, flown, strict=True)
        ]
    )


def nsga2_designs(spec: JobSpec, policy: Any, evaluations: int, seed: int) -> list[np.ndarray]:
    """NSGA-II's final non-dominated designs after about ``evaluations`` design evaluations, each design
    scored (mass, mean settling) by ``policy`` on ``diffsim.design_slews`` slews of the training physics."""
    rng = np.random.default_rng([seed, 11])

    def score(grids: list[np.ndarray]) -> np.ndarray:
        flown = fly_grids(spec, policy, grids, spec.diffsim.design_slews, int(rng.integers(2**31)), exact=False)
        return scores(spec, grids, flown)

    return nsga2_search(spec, score, evaluations // POPULATION, seed)


#: The paper's method on the same problem (its GA, with NSGA-II's selection for two objectives): every
#: design the search draws gets a controller of its own, a `diffsim-control` run of ``GA_UPDATES``
#: updates on that design alone, trained as the preset trains (its mission, flight conditions and
#: learner); generations of ``GA_POPULATION``, for as many updates in all as the co-design run trained
#: (240 on the presets: two generations of eight designs).
GA_POPULATION, GA_UPDATES = 8, 15


def own_controller(spec: JobSpec, grid: np.ndarray, updates: int, seed: int) -> torch.nn.Module:
    """The actor of a `diffsim-control` run of ``updates`` updates on ``grid`` alone, with ``spec``'s
    mission, flight conditions and learner settings (the GA's inner loop)."""
    from modsat_core.training.diffsim import DiffsimRun

    d = spec.model_dump(mode="json")
    steps = updates * spec.diffsim.batch_size * spec.diffsim.window_steps
    d.update(algorithm="diffsim-control", seed=seed, name=f"{spec.name}-ga-inner")
    d["design"]["fixed_design"] = np.asarray(grid).tolist()
    d["objective"]["trade_off_prices_s_per_kg"] = []
    d["diffsim"]["front_search_designs"] = 0
    d["training"].update(total_env_steps=steps, eval_every_steps=steps, checkpoint_every_steps=steps, select_top_k=1)
    run = DiffsimRun(parse_spec(d))
    run.run(lambda _p: None, lambda _c: None, lambda: False)
    return run.chosen()[0].double().eval()


def ga_inner_front(
    spec: JobSpec,
    updates: int,
    slews: int,
    seed: int,
    bench_seed: int,
    population: int = GA_POPULATION,
    per_design: int = GA_UPDATES,
) -> dict[str, Any]:
    """The GA with an inner learner (``population`` designs a generation, ``per_design`` updates each) for
    at most ``updates`` updates in all:
    each design scored by its own controller on ``diffsim.design_slews`` slews of the training physics;
    then every design it trained flown by its own controller on the bench slews, and their front.
    ``train_s``: the search (its training and scoring); ``wall_s`` with the bench flights."""
    rng = np.random.default_rng([seed, 13])
    trained: list[tuple[np.ndarray, torch.nn.Module]] = []

    def score(grids: list[np.ndarray]) -> np.ndarray:
        flown: list[list[dict]] = []
        for g in grids:
            if not (g >= ACTUATOR).any():  # nothing to train: scored as flying nothing
                flown.append([])
                continue
            actor = own_controller(spec, g, per_design, (seed * 7919 + len(trained)) % 2**31)
            trained.append((g, actor))
            flown += fly_grids(spec, actor, [g], spec.diffsim.design_slews, int(rng.integers(2**31)), exact=False)
        return scores(spec, grids, flown)

    start = time.perf_counter()
    nsga2_search(spec, score, updates // (population * per_design), seed, population)
    train_s = time.perf_counter() - start
    records = [fly_records(spec, actor, [g], slews, bench_seed)[0] for g, actor in trained]
    return {
        "front": front_from(records),
        "designs_trained": len(trained),
        "updates": per_design * len(trained),
        "train_s": round(train_s, 1),
        "wall_s": round(time.perf_counter() - start, 1),
    }


def fly_records(spec: JobSpec, policy: Any, grids: list[np.ndarray], slews: int, seed: int) -> list[dict[str, Any]]:
    """Each of ``grids`` (duplicates flown once) flown by ``policy`` on the bench slews: its record."""
    episode_s = spec.mission.episode_steps * spec.mission.control_dt_s
    unique: list[np.ndarray] = []
    for g in grids:
        if not any(np.array_equal(g, u) for u in unique):
            unique.append(g)
    flown = fly_grids(spec, policy, unique, slews, seed, exact=True)
    return [point_record(spec, g, e, episode_s) for g, e in zip(unique, flown, strict=True)]


def front_from(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The non-dominated set (mass, median settling) of the records that land every slew, lightest first."""
    landed = [r for r in records if r["success"] >= 1.0]
    if not landed:
        return []
    keep = nondominated(np.asarray([[r["mass_kg"], r["median_settling_s"]] for r in landed]))
    return sorted([r for r, k in zip(landed, keep, strict=True) if k], key=lambda r: r["mass_kg"])


def front_of(spec: JobSpec, policy: Any, grids: list[np.ndarray], slews: int, seed: int) -> list[dict[str, Any]]:
    """The grids flown on the bench slews, and their non-dominated set (those landing every slew)."""
    return front_from(fly_records(spec, policy, grids, slews, seed))


def objectives(front: list[dict]) -> np.ndarray:
    """(P, 2): each point's mass (kg) and median settling time (s)."""
    return np.asarray([[p["mass_kg"], p["median_settling_s"]] for p in front])


def beats(points: list[dict], front: list[dict], margin: float = MARGIN) -> int:
    """How many of ``points`` are better than some point of ``front`` by more than ``margin`` in both
    mass and median settling time."""
    return sum(
        any(
            p["mass_kg"] < (1 - margin) * q["mass_kg"]
            and p["median_settling_s"] < (1 - margin) * q["median_settling_s"]
            for q in front
        )
        for p in points
    )


def bench_pareto(
    preset: str,
    seeds: list[int],
    designs: int = 100,
    slews: int = 32,
    on_seed: Callable[[dict[str, Any]], object] | None = None,
    ga: bool = True,
) -> dict[str, Any]:
    """The report (module docstring); ``on_seed`` gets the report so far after each seed (a long bench
    keeps what it measured if it is stopped); without ``ga`` the GA's row is left out."""
    out: dict[str, Any] = {"preset": preset, "cpu": _cpu_model(), "slews": slews, "rows": []}
    for seed in seeds:
        data = get_preset(preset).model_dump(mode="json")
        data["seed"] = seed
        spec = parse_spec(data)
        files, train_s, wall = timed_train(spec)
        curve = json.loads(files["curve.json"])
        policy, _, _ = load_policy(files["policy.pt"])
        policy = policy.double().eval()
        ref = reference_point(spec)
        bench_seed = spec.evaluation.seed + 3
        drawn = sum(len(spec.objective.trade_off_prices_s_per_kg) for _ in curve.get("designs", []))
        evaluations = drawn * max(4, spec.diffsim.design_batch // len(spec.objective.trade_off_prices_s_per_kg))
        evaluations += curve.get("front_search", {}).get("designs_flown", 0)  # the run's local search
        run_front = [np.asarray(p["grid"], dtype=np.int64) for p in curve["front"]]
        fronts = {
            "codesign": front_of(spec, policy, run_front, slews, bench_seed),
            "nsga2": front_of(spec, policy, nsga2_designs(spec, policy, evaluations, seed), slews, bench_seed),
            "random": front_of(spec, policy, random_designs(spec, designs, seed), slews, bench_seed),
        }
        updates = spec.training.total_env_steps // (spec.diffsim.batch_size * spec.diffsim.window_steps)
        inner = ga_inner_front(spec, updates, slews, seed, bench_seed) if ga else None
        if inner is not None:
            fronts["ga_inner"] = inner["front"]
        by_grid = {json.dumps(p["grid"]): p for p in curve["front"]}
        for p in fronts["codesign"]:  # the run's own flight-condition table and verdict for its points
            own = by_grid.get(json.dumps(p["grid"]), {})
            p.update({k: own[k] for k in ("conditions", "meets", "reasons") if k in own})
        hv = {
            k: hypervolume(np.asarray([[p["mass_kg"], p["median_settling_s"]] for p in f]), ref)
            for k, f in fronts.items()
        }
        meeting = [p for p in curve["front"] if p.get("meets")]
        lightest = min(meeting, key=lambda p: p["mass_kg"]) if meeting else None
        done: dict[str, dict[str, Any]] = {  # what each method spent
            "codesign": {
                "train_s": round(train_s, 1),
                "wall_s": round(wall, 1),
                "design_evaluations": evaluations,
                "controller_updates": updates,
            },
            "nsga2": {"design_evaluations": evaluations},
            "random": {"design_evaluations": designs},
        }
        if inner is not None:
            done["ga_inner"] = {
                "train_s": inner["train_s"],
                "wall_s": inner["wall_s"],
                "design_evaluations": inner["designs_trained"],
                "controller_updates": inner["updates"],
            }
        for method, front in fronts.items():
            out["rows"].append(
                {
                    "method": method,
                    "seed": seed,
                    "train_s": done[method].get("train_s"),
                    "wall_s": done[method].get("wall_s"),
                    "design_evaluations": done[method]["design_evaluations"],
                    "controller_updates": done[method].get("controller_updates"),
                    "controller": "each design its own" if method == "ga_inner" else "the co-design run's",
                    "front": front,
                    "hypervolume_kg_s": hv[method],
                    "reference_point": {"mass_kg": ref[0], "settling_s": ref[1]},
                    "hypervolume_ratio_codesign_to_this": (hv["codesign"] / hv[method]) if hv[method] else None,
                    "points_beating_codesign_by_2pct": beats(front, fronts["codesign"]) if method != "codesign" else 0,
                    "lightest_meeting_requirements": (
                        {k: lightest[k] for k in ("grid", "mass_kg", "median_settling_s", "power_W")}
                        if method == "codesign" and lightest
                        else None
                    ),
                }
            )
        if on_seed is not None:
            on_seed(out)
    return out
