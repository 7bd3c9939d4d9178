"""What a viewer tab writes about its runs: the title, the design-and-evaluation notes, the
slews to pick from, the readout at one instant and the time plots' lines. Pure functions of the
runs and episodes (no viser), so the session only puts them on screen."""

from __future__ import annotations

import numpy as np

from modsat_core.grid import describe

from ..run import Episode, RunData

PLOTS = (
    ("error", "error angle (deg)"),
    ("rate", "body rate |omega| (rad/s)"),
    ("momentum", "wheel momentum |h| (N m s)"),
)
#: The main run's line, then the compared run's.
PLOT_COLORS = ("#ff7f0e", "#1f77b4")


def run_label(run: RunData) -> str:
    """How a run is named beside its satellite and in the plots' legends."""
    return f"{run.short_algorithm}: {run.title}"


def heading(runs: list[RunData]) -> str:
    """The tab's heading (markdown)."""
    if not runs:
        return "**modsat viewer**: no finished run yet. Refresh the list once a job has succeeded."
    names = " vs ".join(f"{r.short_algorithm} ({r.title})" for r in runs)
    return f"**modsat viewer**: {names}"


def design_and_evaluation(runs: list[RunData]) -> str:
    """The legend of the scene, then each run's design and evaluation summary (markdown)."""
    lines = [
        "Grey cubes: structure modules; orange cubes: reaction-wheel actuators. "
        "Thick axes: body frame (x red, y green, z blue); faint copy: target attitude.",
        "",
    ]
    for r in runs:
        mass = r.design.mass_kg
        lines.append(
            f"**{r.short_algorithm}: {r.title}**: {describe(r.modules, r.actuators)}"
            + (f", {mass:.1f} kg" if mass is not None else "")
        )
        ev = r.evaluation
        for c, name in ((ev and ev.policy, "policy"), (ev and ev.pd_baseline, "PD baseline")):
            if c:
                s = c.summary
                lines.append(
                    f"- {name}: success {100 * s.success_rate:.0f} % of "
                    f"{s.episodes} slews, mean return {s.mean_return or 0:.1f}"
                )
        lines.append("")
    return "\n".join(lines)


def slew_options(runs: list[RunData], controller: str) -> list[str]:
    """The "Slew" dropdown's options for ``controller``: as many as the run with the most,
    described from the main run's (``"-"`` when there is none)."""
    n = max([len(r.episodes.get(controller, [])) for r in runs] + [0])
    first = runs[0].episodes.get(controller, []) if runs else []
    return [f"{i + 1}: {first[i].describe()}" if i < len(first) else f"{i + 1}" for i in range(n)] or ["-"]


def readout_line(run: RunData, ep: Episode, i: int, t: float, *, alone: bool) -> str:
    """One run's error, rate and wheel momentum at sample ``i`` (time ``t`` s into the slew)."""
    # Side by side, each line names its run (both could be RL, or both GA).
    who = run.short_algorithm if alone else f"{run.short_algorithm} {run.title}"
    return (
        f"**{who}** error {ep.error_deg[i]:.1f} deg, rate "
        f"{ep.rate_rad_s[i]:.3f} rad/s, wheels {ep.wheel_momentum_Nms[i]:.4f} N m s"
        + (" (episode over)" if t > ep.duration_s + 1e-9 else "")
    )


def series(ep: Episode | None, times: np.ndarray, what: str) -> np.ndarray:
    """Values of ``what`` (a key of PLOTS) at ``times`` (hold-last beyond the end of the episode)."""
    if ep is None or not len(ep.t_s):
        return np.full(len(times), np.nan)
    v = {"error": ep.error_deg, "rate": ep.rate_rad_s, "momentum": ep.wheel_momentum_Nms}[what]
    return v[ep.indices_at(times + ep.t_s[0])].astype(np.float64)


def plot_legend(runs: list[RunData]) -> tuple[dict, ...]:
    """uPlot's ``series`` of a time plot: the time axis, then one coloured line per run."""
    return (
        {"label": "t (s)"},
        *({"label": run_label(r), "stroke": c, "width": 2} for r, c in zip(runs, PLOT_COLORS)),
    )
