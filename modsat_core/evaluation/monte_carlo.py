"""Monte-Carlo evaluation: a fixed, seeded set of slews flown in one batch.

Episode ``i`` of a set with seed ``s`` is drawn from ``numpy.random.default_rng([s, i])``,
so it is the same slew whatever the number of episodes or the controller. Under flight conditions
(:func:`monte_carlo_conditions`) episode ``i`` of every condition is that slew too (with the
condition's slew range, the same draw of axis and angle fraction), and the random directions of
its conditions come from ``default_rng([s, i, 3])``: the same for every condition and controller.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, cast

import numpy as np
import torch
from torch import Tensor

from modsat_core.sim.conditions import (
    Axes,
    Flight,
    RowConditions,
    condition_mission_range,
    max_delay,
    perturb,
)
from modsat_core.sim.mission import draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.evaluation import Condition
from modsat_core.spec.jobspec import Mission, ModuleCatalog

Controller = Callable[[SlewSim], Tensor]  # sim -> action (B, K, 3) in [-1, 1]


def episode_rngs(seed: int, episodes: int, start: int = 0) -> list[np.random.Generator]:
    return [np.random.default_rng([seed, i]) for i in range(start, start + episodes)]


@dataclass
class MonteCarloResult:
    episodes: list[dict]  # one dict of metrics per episode (python floats / bools)
    trajectories: list[dict]  # time histories of the first few episodes

    def summary(self, tolerances_deg: tuple[float, ...] = ()) -> dict:
        """Aggregate figures: success rate, median ratio to the eigenaxis bound, etc."""
        ep = self.episodes
        n = len(ep)

        def median(key):
            vals = [e[key] for e in ep if e[key] is not None and math.isfinite(e[key])]
            return float(np.median(vals)) if vals else None

        out = {
            "episodes": n,
            "success_rate": sum(e["success"] for e in ep) / n,
            "safety_violations": sum(e["safety_violation"] for e in ep),
            "mean_return": float(np.mean([e["return"] for e in ep])),
            "std_return": float(np.std([e["return"] for e in ep])),
            "median_final_error_deg": median("final_error_deg"),
            "median_final_rate_rad_s": median("final_rate_rad_s"),
            "median_settling_time_s": median("settling_time_s"),
            "median_slew_time_ratio": median("slew_time_ratio"),
            "median_effort_Nms": median("effort_Nms"),
            "max_peak_rate_rad_s": max(e["peak_rate_rad_s"] for e in ep),
        }
        for tol in tolerances_deg:
            ok = [
                e["final_error_deg"] <= tol
                and e["final_rate_rad_s"] <= e["rate_tolerance_rad_s"]
                and not e["safety_violation"]
                for e in ep
            ]
            out[f"success_rate_at_{tol:g}_deg"] = sum(ok) / n
        return out


def _to_python(v: Tensor) -> float | bool | None:
    x = v.item()
    if isinstance(x, float) and math.isnan(x):
        return None
    return x


def monte_carlo(
    designs: list[Design] | Design,
    controller: Controller | Callable[[SlewSim], Controller],
    mission: Mission,
    modules: ModuleCatalog,
    *,
    episodes: int,
    seed: int,
    record: int = 0,
    dtype: torch.dtype = torch.float64,
    device: str = "cpu",
    slews: int | None = None,
    compiled: bool = False,
) -> MonteCarloResult:
    """Fly ``episodes`` seeded slews in one batch and collect their metrics.

    Args:
        designs: one design for all episodes, or one per episode.
        controller: ``f(sim) -> action``, or a class whose constructor takes the sim and
            whose instances are such functions (e.g. :class:`~modsat_core.sim.pd.PDController`).
        record: number of leading episodes whose time histories are returned.
        slews: if set, episode i flies slew ``i % slews`` of the seed's set (several designs
            on the same slews); else episode i flies slew i.
        compiled: the physics step fused by ``torch.compile`` (``diffsim.compiled``'s design scoring,
            ``evaluation.compiled``'s evaluation).
    """
    if isinstance(designs, Design):
        designs = [designs] * episodes
    if len(designs) != episodes:
        raise ValueError(f"{len(designs)} designs for {episodes} episodes")
    sim = SlewSim.from_designs(designs, mission, modules, dtype=dtype, device=device, compiled=compiled)
    draws = [draw_episode(r, mission) for r in episode_rngs(seed, slews or episodes)]
    sim.reset(list(range(episodes)), [draws[i % len(draws)] for i in range(episodes)])
    return _fly(Flight(sim), controller, mission, record)


def monte_carlo_conditions(
    designs: list[Design] | Design,
    controller: Controller | Callable[[SlewSim], Controller],
    mission: Mission,
    modules: ModuleCatalog,
    conditions: list[Condition],
    *,
    episodes: int,
    seed: int,
    dtype: torch.dtype = torch.float64,
    device: str = "cpu",
    compiled: bool = False,
) -> dict[str, MonteCarloResult]:
    """:func:`monte_carlo` under each of ``conditions`` (all in one batch): condition name -> result.

    Row ``c * episodes + i`` flies episode ``i`` of the seed's set under condition ``c``; the
    controller believes the design's inertia and sees measured states (:class:`Flight`). ``compiled``:
    the physics step fused by ``torch.compile`` (``evaluation.compiled``)."""
    if isinstance(designs, Design):
        designs = [designs] * episodes
    if len(designs) != episodes:
        raise ValueError(f"{len(designs)} designs for {episodes} episodes")
    if not conditions:
        return {}
    C = len(conditions)
    rows = RowConditions.of(conditions).take(np.repeat(np.arange(C), episodes))
    axes_rngs = [np.random.default_rng([seed, i, 3]) for i in range(episodes)]
    axes = [Axes.draw(r, 1) for r in axes_rngs]
    ax = Axes(
        *(np.tile(np.concatenate([getattr(a, f) for a in axes]), (C, 1)) for f in ("inertia", "tumble", "disturbance"))
    )
    I_model = np.tile(np.stack([d.I_B for d in designs]), (C, 1, 1))
    draws = []
    for c in conditions:
        m = condition_mission_range(mission, c)
        draws += [draw_episode(r, m) for r in episode_rngs(seed, episodes)]
    I_true, draws = perturb(I_model, draws, rows, ax)
    all_designs = [replace(d, I_B=I) for d, I in zip(designs * C, I_true)]
    sim = SlewSim.from_designs(all_designs, mission, modules, dtype=dtype, device=device, compiled=compiled)
    sim.reset(list(range(C * episodes)), draws)
    flight = Flight(sim, max_delay=max_delay(conditions), seed=seed)
    kw: dict[str, Any] = dict(dtype=sim.dtype, device=sim.device)
    flight.set_rows(torch.arange(C * episodes), rows, torch.as_tensor(I_model, **kw))
    mc = _fly(flight, controller, mission, 0)
    return {
        c.name: MonteCarloResult(episodes=mc.episodes[k * episodes : (k + 1) * episodes], trajectories=[])
        for k, c in enumerate(conditions)
    }


def _fly(
    flight: Flight, controller: Controller | Callable[[SlewSim], Controller], mission: Mission, record: int
) -> MonteCarloResult:
    """Fly the flight's episodes (reset) to their end with ``controller`` and collect them."""
    sim = flight.sim
    episodes = sim.B
    if isinstance(controller, type):  # built on what it knows (no noise drawn: every controller meets the same)
        controller = controller(flight.view(measured=False))
    done = torch.zeros(episodes, dtype=torch.bool, device=sim.device)
    final: dict[str, Tensor] = {}
    rec = min(record, episodes)
    hist: dict[str, list] = {k: [] for k in ("t_s", "q_BN", "omega_B", "h_B", "tau_c_B", "error_deg")}

    def snapshot(tau_c: Tensor) -> None:
        st = sim.state
        hist["t_s"].append(st.t_s[:rec].clone())
        hist["q_BN"].append(st.q_BN[:rec].clone())
        hist["omega_B"].append(st.omega_B[:rec].clone())
        hist["h_B"].append(st.h_B[:rec].sum(dim=1).clone())
        hist["tau_c_B"].append(tau_c[:rec].clone())
        hist["error_deg"].append(sim.phi_prev[:rec] * 180.0 / math.pi)

    if rec:
        snapshot(torch.zeros(episodes, 3, dtype=sim.dtype, device=sim.device))
    for _ in range(mission.episode_steps):
        with torch.no_grad():
            action = flight.act(cast(Controller, controller))  # a Controller once a class was instantiated
        out = sim.step(action)
        if rec:
            snapshot(out.tau_c_B)
        ended = (out.terminated | out.truncated) & ~done
        if bool(ended.any()):
            for key, val in out.final.items():
                if key not in final:
                    final[key] = torch.zeros_like(val)
                final[key][ended] = val[ended]
        done |= ended
        if bool(done.all()):
            break
    per_episode: list[dict[str, Any]] = []
    for i in range(episodes):
        row = {k: _to_python(v[i]) for k, v in final.items()}
        row["rate_tolerance_rad_s"] = mission.rate_tolerance_rad_s
        per_episode.append(row)
    trajectories = []
    for i in range(rec):
        stack = {k: torch.stack([h[i] for h in v]).cpu().numpy() for k, v in hist.items()}
        # Stop a trajectory where its episode ended (a safety violation ends it early).
        n = int(round(per_episode[i]["duration_s"] / mission.control_dt_s)) + 1
        trajectories.append(
            {
                **{k: v[:n].tolist() for k, v in stack.items()},
                "q_TN": sim.q_TN[i].cpu().tolist(),
                "metrics": per_episode[i],
            }
        )
    return MonteCarloResult(episodes=per_episode, trajectories=trajectories)
