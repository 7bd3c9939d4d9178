"""The trade-off's local search: after training, the run's controller flies neighbours of the front's
candidates, and the non-dominated ones join the candidates (docs/requirements.md, "The trade-off").

The design distributions and the archive find the front's region; two designs of the same mass there can
still differ by a few percent in settling time by where their wheel units sit, and a draw that lands on
the better arrangement is luck. The search asks for it directly: each round takes the non-dominated
points flown so far (over mass and mean settling time, a failed slew counting the episode, among those
that landed every slew: the distributions' and NSGA-II's smoother statistic; on 8 slews the median picked
a worse arrangement at the same mass, docs/lab/2026-12-07-front-local-search.md), draws
neighbours of them (one free cell changed to another part, or two free cells of different parts swapped;
the payload kept, a cell cut off from it dropped) that were never flown, and flies them all on the same
``design_slews`` slews of the training physics (common slews, so that two neighbours differ by their
design, not their slews). It stops after ``diffsim.front_search_designs`` flown designs, or where a round
finds no new neighbour. The starting candidates' own flights count in that budget: the bench gives
NSGA-II as many design evaluations as the run made, this search included.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from modsat_core.grid import ACTUATOR, EMPTY
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.limits import FRONT_SEARCH_ROUND
from modsat_core.spec.parts import design_mass_kg
from modsat_core.training.diffsim_codesign import cell_types, fixed_cells, fly_grids, satellites

#: How many tries a round makes per neighbour it wants before it gives up on a parent (every move of a
#: small grid may already have been flown).
TRIES_PER_NEIGHBOUR = 20


def mean_time_s(episodes: list[dict], episode_s: float) -> float:
    """Mean settling time, a failed slew counting the whole episode (no rows: worse than any design)."""
    if not episodes:
        return 2.0 * episode_s
    return float(np.mean([e["settling_time_s"] if e["success"] else episode_s for e in episodes]))


def nondominated(points: np.ndarray) -> np.ndarray:
    """(P,) bool: the points (P, 2) no other point is at least as good as in both and better in one
    (moocore's; minimised)."""
    import moocore

    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    return np.asarray(moocore.is_nondominated(np.asarray(points, dtype=np.float64)), dtype=bool)


def _adjacent(occupied: np.ndarray) -> np.ndarray:
    """(N, N, N) bool: the cells face-adjacent to an occupied one, or occupied."""
    out = occupied.copy()
    for axis in range(3):
        for shift in (1, -1):
            moved = np.roll(occupied, shift, axis=axis)
            edge: list[slice | int] = [slice(None)] * 3
            edge[axis] = 0 if shift == 1 else -1
            moved[tuple(edge)] = False  # no wrap-around
            out |= moved
    return out


def neighbours(
    grid: np.ndarray,
    n: int,
    rng: np.random.Generator,
    seen: set[bytes],
    fixed: np.ndarray,
    types: np.ndarray,
    cell_types: int,
) -> list[np.ndarray]:
    """Up to ``n`` satellites one move from ``grid`` that are not in ``seen`` (added to it): a free cell
    changed to another part, or two free cells of different parts swapped; the satellite is what stays
    face-connected to the fixed cells, and it carries a wheel unit."""
    g = np.asarray(grid, dtype=np.int64)
    free = ~fixed
    occupied = np.flatnonzero((free & (g != EMPTY)).reshape(-1))
    reachable = np.flatnonzero((free & _adjacent(g != EMPTY)).reshape(-1))
    out: list[np.ndarray] = []
    if len(reachable) == 0:
        return out
    for _ in range(n * TRIES_PER_NEIGHBOUR):
        if len(out) >= n:
            break
        raw = g.reshape(-1).copy()
        if len(occupied) and rng.random() < 0.5:  # swap two free cells of different parts
            a, b = int(rng.choice(occupied)), int(rng.choice(reachable))
            if raw[a] == raw[b]:
                continue
            raw[a], raw[b] = raw[b], raw[a]
        else:  # change one free cell to another part
            c = int(rng.choice(reachable))
            raw[c] = (raw[c] + 1 + int(rng.integers(cell_types - 1))) % cell_types
        h = satellites(raw.reshape((1, *g.shape)), fixed, types)[0]
        key = h.tobytes()
        if key in seen or not (h >= ACTUATOR).any():
            continue
        seen.add(key)
        out.append(h)
    return out


def local_search(
    spec: JobSpec,
    policy: Any,
    starts: list[np.ndarray],
    budget: int,
    on_round: Callable[[int, int], None] = lambda _flown, _budget: None,
) -> tuple[list[dict[str, Any]], int]:
    """The search (module docstring) from ``starts``, flown by ``policy`` (float32, the training physics).

    Returns the non-dominated points it flew over (mass, mean settling time), lightest first, each
    ``{"grid", "mass_kg", "mean_time_s", "start"}`` (``start``: the index in ``starts`` of the candidate
    it descends from), and how many designs it flew. ``on_round(flown, budget)`` is told before each round."""
    d = spec.diffsim
    fixed, types = fixed_cells(spec.design, spec.objective, spec.modules)
    T = cell_types(spec)
    episode_s = spec.mission.episode_steps * spec.mission.control_dt_s
    rng = np.random.default_rng([spec.seed, 13])
    slews_seed = int(rng.integers(2**31))
    points: list[dict[str, Any]] = []
    expanded: set[bytes] = set()
    seen: set[bytes] = set()

    def fly(grids: list[np.ndarray], origin: list[int]) -> None:
        flown = fly_grids(spec, policy, grids, d.design_slews, slews_seed, exact=False)
        for g, eps, o in zip(grids, flown, origin, strict=True):
            if eps and all(e["success"] for e in eps):
                points.append(
                    {
                        "grid": g,
                        "mass_kg": design_mass_kg(g, spec.modules),
                        "mean_time_s": mean_time_s(eps, episode_s),
                        "start": o,
                    }
                )

    first: list[tuple[np.ndarray, int]] = []
    for i, g in enumerate(starts[:budget]):
        g = np.asarray(g, dtype=np.int64)
        if g.tobytes() not in seen and (g >= ACTUATOR).any():
            seen.add(g.tobytes())
            first.append((g, i))
    on_round(0, budget)
    fly([g for g, _ in first], [i for _, i in first])
    spent = len(first)

    def front() -> list[dict[str, Any]]:
        if not points:
            return []
        keep = nondominated(np.asarray([[p["mass_kg"], p["mean_time_s"]] for p in points]))
        return sorted([p for p, k in zip(points, keep, strict=True) if k], key=lambda p: p["mass_kg"])

    while spent < budget:
        current = front()
        if not current:
            break
        fresh = [p for p in current if p["grid"].tobytes() not in expanded]
        parents = fresh or current
        want = min(FRONT_SEARCH_ROUND, budget - spent)
        each = max(1, -(-want // len(parents)))
        grids: list[np.ndarray] = []
        origin: list[int] = []
        for p in parents:
            expanded.add(p["grid"].tobytes())
            for h in neighbours(p["grid"], min(each, want - len(grids)), rng, seen, fixed, types, T):
                grids.append(h)
                origin.append(p["start"])
            if len(grids) >= want:
                break
        if not grids:
            break
        on_round(spent, budget)
        fly(grids, origin)
        spent += len(grids)
    return front(), spent
