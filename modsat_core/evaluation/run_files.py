"""A run's evaluations and output files: the learning-curve point, the final Monte-Carlo
(policy and PD baseline on the same slews), the design report, the curve PNG and the files
a finished run writes (docs/learning.md, "Outputs of a run").
"""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from modsat_core.agent.export import export_files
from modsat_core.agent.policy import controller_for
from modsat_core.agent.policy_file import policy_bytes
from modsat_core.artefacts import (
    ConditionEvaluation,
    CurveFile,
    CurvePoint,
    DesignReport,
    EvaluationReport,
    RunSummary,
    Trajectories,
    flight_failures,
)
from modsat_core.codesign.mdp import effective_invalid_penalty
from modsat_core.evaluation.monte_carlo import monte_carlo, monte_carlo_conditions
from modsat_core.grid import ACTUATOR, EMPTY, is_valid
from modsat_core.sim.morphology import design_mass_properties
from modsat_core.sim.pd import PDController
from modsat_core.sim.slew import Design
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.parts import design_mass_kg, design_power_W
from modsat_core.spec.requirements import requirement_verdict

#: Final-evaluation tolerances reported beside the mission's own.
REPORT_TOLERANCES_DEG = (0.25, 1.0)


def curve_seed(spec: JobSpec) -> int:
    """Seed of the learning-curve slews: distinct from the final evaluation's set."""
    return (spec.evaluation.seed + 7919) % (2**31)


def evaluate_design(
    actor: torch.nn.Module,
    grid: np.ndarray,
    spec: JobSpec,
    *,
    episodes: int,
    seed: int,
    record: int = 0,
    dtype=torch.float32,
    device: str = "cpu",
):
    """Monte-Carlo of the actor flying ``grid``; None if the grid is not a valid satellite."""
    if not is_valid(grid):
        return None
    return monte_carlo(
        Design.from_grid(grid, spec.modules),
        controller_for(actor, grid, spec),
        spec.mission,
        spec.modules,
        episodes=episodes,
        seed=seed,
        record=record,
        dtype=dtype,
        device=device,
    )


def curve_point(
    actor: torch.nn.Module, grid: np.ndarray, spec: JobSpec, env_steps: int, updates: int, penalty: float
) -> dict:
    mc = evaluate_design(actor, grid, spec, episodes=spec.training.eval_episodes, seed=curve_seed(spec))
    n_mod = int((np.asarray(grid) != EMPTY).sum())
    n_act = int((np.asarray(grid) >= ACTUATOR).sum())
    point: dict[str, Any] = {
        "env_steps": env_steps,
        "updates": updates,
        "valid": mc is not None,
        "modules": n_mod,
        "actuators": n_act,
    }
    # Success at the mission's tolerance and at the reported ones (0.25 and 1 deg), so that a
    # curve shows how close to the paper's 0.25 deg a run that lands at 1 deg is.
    tol_keys = [f"success_rate_at_{t:g}_deg" for t in REPORT_TOLERANCES_DEG]
    if mc is None:
        point.update({"mean_return": penalty, "success_rate": 0.0, **dict.fromkeys(tol_keys, 0.0)})
    else:
        s = mc.summary(REPORT_TOLERANCES_DEG)
        point.update(
            {
                k: s[k]
                for k in ("mean_return", "success_rate", *tol_keys, "median_final_error_deg", "median_slew_time_ratio")
            }
        )
    return CurvePoint.model_validate(point).to_dict()


def design_report(grid: np.ndarray, spec: JobSpec) -> DesignReport:
    """``design.json``: the grid, its module counts and (with modules) its mass properties."""
    grid = np.asarray(grid)
    if not (grid != EMPTY).any():
        return DesignReport.of(grid)
    mp = design_mass_properties(grid, spec.modules)
    return DesignReport.of(
        grid,
        mass_kg=float(mp.mass_kg),
        com_grid_m=np.asarray(mp.com_grid_m).tolist(),
        inertia_kgm2=np.asarray(mp.inertia_B_kgm2).tolist(),
        principal_inertia_kgm2=np.linalg.eigvalsh(mp.inertia_B_kgm2).tolist(),
    )


def final_evaluation(
    actor: torch.nn.Module,
    grid: np.ndarray,
    spec: JobSpec,
    episodes: int | None = None,
    on_stage: Callable[[int, int, str], None] | None = None,
) -> dict:
    """The policy and the PD baseline on the same design and the same seeded slews.

    ``on_stage(i, n, what)`` is told before each of its ``n`` stages (the policy and PD on the
    nominal slews, then under the flight conditions) starts: ``modsat eval`` prints it."""
    ev = spec.evaluation
    # the policy and PD on the nominal slews, then (with conditions) under the flight conditions
    stage = _Stages(on_stage, 2 + 2 * bool(ev.conditions))
    n = episodes or ev.episodes
    tols = tuple(sorted({*REPORT_TOLERANCES_DEG, spec.mission.tolerance_deg}))
    out: dict[str, Any] = {"episodes": n, "seed": ev.seed, "design_valid": bool(is_valid(grid))}
    if not out["design_valid"]:
        pen = effective_invalid_penalty(spec.design, spec.mission)
        out["policy"] = {
            "summary": {"episodes": n, "success_rate": 0.0, "mean_return": pen, "std_return": 0.0},
            "episodes": [],
        }
        out["pd_baseline"] = None
        out["trajectories"] = {"policy": [], "pd_baseline": []}
        return out
    design = Design.from_grid(grid, spec.modules)
    kw: dict[str, Any] = dict(
        episodes=n, seed=ev.seed, record=min(ev.trajectories, n), dtype=torch.float64, compiled=ev.compiled
    )
    stage(f"the policy on {n} nominal slews")
    mc = monte_carlo(design, controller_for(actor, grid, spec), spec.mission, spec.modules, **kw)
    stage(f"PD on the same {n} slews")
    pd = monte_carlo(design, PDController, spec.mission, spec.modules, **kw)
    out["policy"] = {"summary": mc.summary(tols), "episodes": mc.episodes}
    out["pd_baseline"] = {"summary": pd.summary(tols), "episodes": pd.episodes}
    out["trajectories"] = {"policy": mc.trajectories, "pd_baseline": pd.trajectories}
    out["conditions"], flown = condition_table(actor, grid, design, spec, tols, n, stage)
    conds = [ConditionEvaluation.model_validate(c) for c in out["conditions"]]
    out["flight_failures"] = [f.to_dict() for f in flight_failures(conds)]
    if spec.requirements is not None:
        out["requirements"] = requirement_verdict(
            spec.requirements,
            spec.mission,
            design_mass_kg(grid, spec.modules),
            design_power_W(grid, spec.modules),
            mc.episodes,
            [(c, flown[c.name]) for c in spec.evaluation.conditions],
        )
    return out


class _Stages:
    """``on_stage(i, n, what)`` of :func:`final_evaluation` told each stage's number as it starts."""

    def __init__(self, on_stage: Callable[[int, int, str], None] | None, total: int):
        self.on_stage, self.total, self.started = on_stage, total, 0

    def __call__(self, what: str) -> None:
        self.started += 1
        if self.on_stage is not None:
            self.on_stage(self.started, self.total, what)


def condition_table(
    actor: torch.nn.Module,
    grid: np.ndarray,
    design: Design,
    spec: JobSpec,
    tols: tuple[float, ...],
    episodes: int,
    on_stage: Callable[[str], None] | None = None,
) -> tuple[list[dict], dict[str, list[dict]]]:
    """The policy and PD under each of ``evaluation.conditions``, on the evaluation's slews (float64,
    the mission's physics): one row per condition with each controller's summary at ``tols``, and the
    policy's slews under each condition by name (the requirements' verdict reads them).
    ``on_stage(what)`` is told before each of its two stages starts (the caller numbers them)."""
    conditions = spec.evaluation.conditions
    if not conditions:
        return [], {}
    ev = spec.evaluation
    kw: dict[str, Any] = dict(episodes=episodes, seed=ev.seed, dtype=torch.float64, compiled=ev.compiled)
    m, mods = spec.mission, spec.modules
    stage = on_stage or (lambda _what: None)
    names = ", ".join(c.name for c in conditions)
    stage(f"the policy on {episodes} slews under each of {len(conditions)} flight conditions ({names})")
    pol = monte_carlo_conditions(design, controller_for(actor, grid, spec), m, mods, conditions, **kw)
    stage(f"PD on the same slews under each of {len(conditions)} flight conditions")
    pd = monte_carlo_conditions(design, PDController, m, mods, conditions, **kw)
    rows = [
        {
            "name": c.name,
            "changes": c.changes(),
            "policy": pol[c.name].summary(tols),
            "pd_baseline": pd[c.name].summary(tols),
        }
        for c in conditions
    ]
    return rows, {c.name: pol[c.name].episodes for c in conditions}


def curve_png(curve: list[dict], title: str) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=100)
    x = [p["env_steps"] for p in curve]
    ax1.plot(x, [p["mean_return"] for p in curve], marker="o", ms=3)
    ax1.set_xlabel("environment steps")
    ax1.set_ylabel("mean evaluation return")
    ax2.plot(x, [100 * p["success_rate"] for p in curve], marker="o", ms=3, color="tab:green", label="mission")
    for tol, style in zip(REPORT_TOLERANCES_DEG, ("--", ":")):
        key = f"success_rate_at_{tol:g}_deg"
        if any(key in p for p in curve):
            ax2.plot(x, [100 * p.get(key, 0.0) for p in curve], style, color="tab:green", label=f"{tol:g} deg")
    ax2.legend(fontsize=7, loc="upper left")
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


def run_files(
    spec: JobSpec,
    curve: list[dict],
    actor: torch.nn.Module,
    grid: np.ndarray,
    extra: dict | None = None,
    on_stage: Callable[[int, int, str], None] | None = None,
) -> tuple[dict[str, bytes], dict]:
    """All output files of a finished run, and a short summary of its evaluation (``on_stage``: as
    :func:`final_evaluation`'s)."""

    raw = final_evaluation(actor, grid, spec, on_stage=on_stage)
    traj = Trajectories.model_validate(raw.pop("trajectories"))
    ev = EvaluationReport.model_validate(raw)
    design = design_report(grid, spec)
    title = f"{spec.name or spec.algorithm}: {spec.design.grid_size}^3, seed {spec.seed}"
    files = {
        "spec.json": spec.model_dump_json(indent=2).encode(),
        "curve.json": CurveFile.model_validate({"algorithm": spec.algorithm, "points": curve, **(extra or {})}).to_json(
            indent=1
        ),
        "curve.png": curve_png(curve, title),
        "design.json": design.to_json(indent=1),
        "evaluation.json": ev.to_json(indent=1),
        "trajectories.json": traj.to_json(),
        "policy.pt": policy_bytes(actor, grid, spec),
    }
    if ev.design_valid:
        files.update(export_files(actor, grid, spec))
    return files, run_summary(ev, design).to_dict()


def run_summary(ev: EvaluationReport, design: DesignReport) -> RunSummary:
    """The short summary of a final evaluation (a job's ``evaluation``; what `modsat eval` prints)."""
    return RunSummary(
        policy=ev.policy.summary,
        pd_baseline=ev.pd_baseline.summary if ev.pd_baseline else None,
        design=design.figures(),
        conditions=ev.conditions,
    )
