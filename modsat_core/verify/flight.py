"""Flying a run's evaluation slews in modsat's own simulator for the Basilisk comparison,
and the metrics both simulators' flights are judged by (modsat_core/verify/run.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from modsat_core.evaluation.monte_carlo import episode_rngs
from modsat_core.evaluation.run_files import REPORT_TOLERANCES_DEG  # the same tolerances as the final evaluation
from modsat_core.sim import quaternion as quat
from modsat_core.sim.mission import EpisodeDraw, draw_episode
from modsat_core.sim.slew import Design, SlewSim
from modsat_core.spec.jobspec import Evaluation, Mission, ModuleCatalog

#: ``controller_factory(sim) -> controller``; ``controller(sim) -> action (B, K, 3) in [-1, 1]``.
ControllerFactory = Callable[[SlewSim], Callable[[SlewSim], torch.Tensor]]


def evaluation_draws(mission: Mission, evaluation: Evaluation, episodes: int) -> list[EpisodeDraw]:
    """The first ``episodes`` slews of modsat's final Monte-Carlo evaluation (same seed, same order)."""
    return [draw_episode(r, mission) for r in episode_rngs(evaluation.seed, episodes)]


def commanded_torque(action: torch.Tensor, sim: SlewSim) -> torch.Tensor:
    """Per-unit body torque command (B, K, 3) N m from an action, as :meth:`SlewSim.step` does."""
    a = action.to(sim.dtype).clamp(-1.0, 1.0) * sim.plant.slots.unsqueeze(-1)
    return a * sim.plant.tau_max_Nm


# ----------------------------------------------------------------------------- histories


@dataclass
class Flight:
    """One slew as flown: the state after every control step (index 0: the start)."""

    t_s: np.ndarray  # (T+1,)
    q_BN: np.ndarray  # (T+1, 4)
    omega_B: np.ndarray  # (T+1, 3)


def fly_modsat(
    design: Design, mission: Mission, modules: ModuleCatalog, draws: list[EpisodeDraw], factory: ControllerFactory
) -> list[Flight]:
    """All slews at once in modsat's simulator (float64); each ends as modsat ends it."""
    B = len(draws)
    sim = SlewSim.from_designs([design] * B, mission, modules, dtype=torch.float64)
    sim.reset(list(range(B)), draws)
    controller = factory(sim)
    hist = [(sim.state.t_s.clone(), sim.state.q_BN.clone(), sim.state.omega_B.clone())]
    steps = torch.full((B,), mission.episode_steps, dtype=torch.long)
    done = torch.zeros(B, dtype=torch.bool)
    for k in range(1, mission.episode_steps + 1):
        with torch.no_grad():
            out = sim.step(controller(sim))
        hist.append((sim.state.t_s.clone(), sim.state.q_BN.clone(), sim.state.omega_B.clone()))
        ended = out.terminated & ~done
        steps[ended] = k
        done |= ended
        if bool(done.all()):
            break
    t, q, w = (torch.stack(x, dim=1).numpy() for x in zip(*hist))
    return [Flight(t[i, : steps[i] + 1], q[i, : steps[i] + 1], w[i, : steps[i] + 1]) for i in range(B)]


# ----------------------------------------------------------------------------- metrics


def _error_angles(q_BN: np.ndarray, q_TN: np.ndarray) -> np.ndarray:
    q_e = quat.multiply(quat.conjugate(torch.from_numpy(np.asarray(q_TN, dtype=float))), torch.from_numpy(q_BN))
    return quat.error_angle(q_e).numpy()


def flight_metrics(f: Flight, q_TN: np.ndarray, mission: Mission) -> dict:
    """Metrics of one slew as modsat defines them (docs/physics.md, "Mission, reward, metrics")."""
    phi = _error_angles(f.q_BN, q_TN)
    rate = np.linalg.norm(f.omega_B, axis=1)
    violated = bool(rate[-1] > mission.rate_limit_rad_s)
    settled_rate = rate[-1] <= mission.rate_tolerance_rad_s and not violated
    tol = mission.tolerance_deg * quat.DEG
    out_of_tol = np.flatnonzero(phi[1:] > tol)
    success = bool(phi[-1] <= tol and settled_rate)
    row = {
        "success": success,
        "final_error_deg": float(phi[-1] / quat.DEG),
        "final_rate_rad_s": float(rate[-1]),
        "settling_time_s": (float(f.t_s[out_of_tol[-1] + 1]) if len(out_of_tol) else 0.0) if success else None,
        "peak_rate_rad_s": float(rate[1:].max()) if len(rate) > 1 else 0.0,
        "safety_violation": violated,
        "duration_s": float(f.t_s[-1]),
    }
    for tol_deg in REPORT_TOLERANCES_DEG:
        row[f"success_{_tol_key(tol_deg)}"] = bool(phi[-1] <= tol_deg * quat.DEG and settled_rate)
    return row


def _tol_key(tol_deg: float) -> str:
    return f"{tol_deg:g}".replace(".", "_") + "deg"


def summarize(rows: list[dict]) -> dict:
    """The side-by-side figures of one simulator over all slews."""

    def median(key):
        vals = [r[key] for r in rows if r[key] is not None]
        return float(np.median(vals)) if vals else None

    n = len(rows)
    out = {"success_rate": sum(r["success"] for r in rows) / n}
    for tol_deg in REPORT_TOLERANCES_DEG:
        key = _tol_key(tol_deg)
        out[f"success_rate_{key}"] = sum(r[f"success_{key}"] for r in rows) / n
    out.update(
        {
            "median_final_error_deg": median("final_error_deg"),
            "max_final_error_deg": max(r["final_error_deg"] for r in rows),
            "median_settling_time_s": median("settling_time_s"),
            "max_peak_rate_rad_s": max(r["peak_rate_rad_s"] for r in rows),
            "safety_violations": sum(r["safety_violation"] for r in rows),
        }
    )
    return out


def attitude_difference_rad(a: Flight, b: Flight) -> float:
    """Largest angle of ``q_a^-1 q_b`` over the control steps both slews flew."""
    n = min(len(a.q_BN), len(b.q_BN))
    d = quat.multiply(quat.conjugate(torch.from_numpy(a.q_BN[:n])), torch.from_numpy(b.q_BN[:n]))
    return float(quat.error_angle(d).max())
