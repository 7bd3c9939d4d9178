"""The figure, the table and the designs of a set of saved runs (a study: one mission, several
seeds, RL co-design and its GA twin), from the files each run wrote (``modsat train --out``).

Torch-free: it reads ``spec.json``, ``curve.json``, ``design.json`` and ``evaluation.json``
(through :class:`~modsat_core.evaluation.run_folder.RunFolder`).

* Learning curves: each run's points (RL: the current policy's evaluation; GA: the best design so
  far, its fitness) held from one evaluation to the next, then mean and standard deviation over the
  seeds of each algorithm at every env-step count where all of them have a point.
* The table: the final Monte-Carlo of each run (success at 0.25 and 1 deg, return, slew time /
  eigenaxis bound) and the PD baseline flown on the same design, mean and std over seeds.
* The designs: how symmetric each one is (products of inertia relative to the largest principal
  moment, centre of mass offset from the grid centre, mirror planes of the grid) and a PNG.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from modsat_core.artefacts import ArtefactError, CurveFile, DesignReport, EvaluationReport, EvaluationSummary
from modsat_core.evaluation.run_folder import RunFolder
from modsat_core.grid import ACTUATOR, EMPTY, describe
from modsat_core.spec.jobspec import JobSpec

LABELS = {
    "td3-codesign": "RL co-design",
    "ga": "GA",
    "td3-control": "TD3 (fixed design)",
    "diffsim-control": "first-order (fixed design)",
    "diffsim-codesign": "first-order co-design",
}
#: The files of a finished run the report reads (:func:`saved_run`).
FILES = ("spec.json", "curve.json", "design.json", "evaluation.json")


@dataclass
class SavedRun:
    """One run of a study. ``path``: its directory, or its job's URL; ``design`` and ``evaluation``
    are None while the run is still training (its curve so far still counts)."""

    path: str
    spec: JobSpec
    curve: CurveFile
    design: DesignReport | None = None
    evaluation: EvaluationReport | None = None

    @property
    def label(self) -> str:
        return LABELS.get(self.spec.algorithm, self.spec.algorithm)


def saved_run(run: RunFolder) -> SavedRun:
    """One finished run, from its folder (a directory, or a job's artefacts); an
    :class:`ArtefactError` names the run and the file that is missing or wrong."""
    return SavedRun(path=run.path, spec=run.spec(), curve=run.curve(), design=run.design(), evaluation=run.evaluation())


def check_comparable(runs: list[SavedRun]) -> None:
    """A study compares methods on one problem: the same grid, modules and mission in every run."""
    if not runs:
        raise ArtefactError("no runs to report")
    first = runs[0]
    for r in runs[1:]:
        for part in ("design", "modules", "mission"):
            a = getattr(first.spec, part).model_dump(exclude={"fixed_design", "repair"})
            if a != getattr(r.spec, part).model_dump(exclude={"fixed_design", "repair"}):
                raise ArtefactError(f"{r.path} and {first.path} differ in spec.{part}: not one study")


def symmetry(design: DesignReport, module_size_m: float) -> dict[str, Any]:
    """How symmetric a design is. ``products_of_inertia_ratio``: the largest product of inertia
    about the centre of mass (grid axes) over the largest principal moment, 0 when the grid axes
    are principal; ``com_offset_modules``: the centre of mass's distance from the grid centre in
    module edges; ``mirror_planes``: how many of the grid's three mid-planes the design, module
    types included, is mirror-symmetric about."""
    g = design.array
    out: dict[str, Any] = {"modules": design.modules, "actuators": design.actuators}
    out["mirror_planes"] = sum(int(np.array_equal(g, np.flip(g, axis=a))) for a in range(3))
    if design.inertia_kgm2 is not None and design.com_grid_m is not None:
        inertia = np.asarray(design.inertia_kgm2)
        off = np.abs(inertia - np.diag(np.diag(inertia))).max()
        out["products_of_inertia_ratio"] = float(off / np.linalg.eigvalsh(inertia).max())
        centre = (design.grid_size - 1) / 2.0 * module_size_m
        offset = np.linalg.norm(np.asarray(design.com_grid_m) - centre) / module_size_m
        out["com_offset_modules"] = float(offset)
    return out


def _std(v: np.ndarray, axis: int | None = None) -> Any:  # over seeds: ddof 1, 0 for one seed
    if (v.shape[0] if axis == 0 else v.size) < 2:
        return 0.0 if axis is None else np.zeros(v.shape[1:])
    return float(v.std(ddof=1)) if axis is None else v.std(axis=axis, ddof=1)


def _mean_std(values: list[float | None]) -> dict[str, Any]:
    v = np.array([x for x in values if x is not None], dtype=np.float64)
    mean, std = (float(v.mean()), _std(v)) if len(v) else (None, None)
    return {"mean": mean, "std": std, "n": int(len(v)), "of": len(values)}


_KEYS = ("return", "success_0.25", "success_1", "slew_ratio")


def _figures(s: EvaluationSummary | None) -> dict[str, float | None]:
    if s is None:
        return dict.fromkeys(_KEYS)
    return {
        "return": s.mean_return,
        "success_0.25": s.success_at(0.25),
        "success_1": s.success_at(1.0),
        "slew_ratio": s.median_slew_time_ratio,
    }


def held_curves(runs: list[SavedRun], key: str) -> dict[str, Any]:
    """Each run's ``key`` held from one curve point to the next (up to its last point), on the union of
    the runs' env steps; mean and std over the runs where every run has a point."""
    steps = np.array(sorted({p.env_steps for r in runs for p in r.curve.points}), dtype=np.int64)
    rows = []
    for r in runs:
        xs = np.array([p.env_steps for p in r.curve.points], dtype=np.int64)
        ys = np.array([np.nan if getattr(p, key) is None else getattr(p, key) for p in r.curve.points], dtype=float)
        if len(xs) == 0:
            rows.append(np.full(len(steps), np.nan))
            continue
        idx = np.searchsorted(xs, steps, side="right") - 1
        rows.append(np.where((idx >= 0) & (steps <= xs[-1]), ys[np.clip(idx, 0, None)], np.nan))
    m = np.array(rows)
    keep = ~np.isnan(m).any(axis=0)
    return {
        "env_steps": [int(s) for s, k in zip(steps, keep) if k],
        "mean": m[:, keep].mean(axis=0).tolist(),
        "std": _std(m[:, keep], axis=0).tolist(),
        "seeds": [r.spec.seed for r in runs],
    }


def condition_means(runs: list[SavedRun]) -> dict[str, Any]:
    """Per flight condition (nominal first, then those every finished run flew): mean and std over
    the runs of the policy's and of PD's success (the mission's tolerance) and violations."""
    evs = [r.evaluation for r in runs if r.evaluation is not None and r.evaluation.pd_baseline is not None]
    if not evs:
        return {}
    names = [c.name for c in evs[0].conditions]
    names = [n for n in names if all(any(c.name == n for c in ev.conditions) for ev in evs)]
    if not names:  # runs from before the conditions, or that flew none: no table
        return {}
    out: dict[str, Any] = {}
    for name in ["nominal", *names]:
        pairs = []
        for ev in evs:
            if name == "nominal":
                assert ev.pd_baseline is not None
                pairs.append((ev.policy.summary, ev.pd_baseline.summary))
            else:
                c = next(c for c in ev.conditions if c.name == name)
                pairs.append((c.policy, c.pd_baseline))
        out[name] = {
            who: {
                "success": _mean_std([p[i].success_rate for p in pairs]),
                "violations": _mean_std([p[i].safety_violations for p in pairs]),
            }
            for i, who in enumerate(("policy", "pd"))
        }
    return out


def study(runs: list[SavedRun]) -> dict[str, Any]:
    """The study's table, curves and designs, by algorithm (JSON-ready)."""
    check_comparable(runs)
    size = runs[0].spec.modules.module_size_m
    out: dict[str, Any] = {"grid_size": runs[0].spec.design.grid_size, "algorithms": {}}
    order = list(LABELS.values())
    for label in sorted({r.label for r in runs}, key=lambda x: (order.index(x) if x in order else len(order), x)):
        group = sorted((r for r in runs if r.label == label), key=lambda r: r.spec.seed)
        done = [r for r in group if r.evaluation is not None]
        pol = [_figures(r.evaluation.policy.summary) for r in done if r.evaluation]
        pd = [
            _figures(r.evaluation.pd_baseline.summary if r.evaluation and r.evaluation.pd_baseline else None)
            for r in done
        ]
        designs = [{"seed": r.spec.seed, "run": r.path, **symmetry(r.design, size)} for r in group if r.design]
        out["algorithms"][label] = {
            "runs": [r.path for r in group],
            "seeds": [r.spec.seed for r in group],
            "env_steps": [max((p.env_steps for p in r.curve.points), default=0) for r in group],
            "finished": len(done),
            "policy": {k: _mean_std([f[k] for f in pol]) for k in _KEYS},
            "pd_on_designs": {k: _mean_std([f[k] for f in pd]) for k in _KEYS},
            "designs": designs,
            "design_means": {
                k: _mean_std([d.get(k) for d in designs])
                for k in ("modules", "actuators", "mirror_planes", "products_of_inertia_ratio", "com_offset_modules")
            },
            "conditions": condition_means(done),
            "curves": {
                "mean_return": held_curves(group, "mean_return"),
                "success_rate": held_curves(group, "success_rate"),
            },
        }
    return out


def _pm(s: dict[str, Any], scale: float = 1.0, fmt: str = "{:.1f}") -> str:
    if s["mean"] is None:
        return "-"
    part = f" ({s['n']} of {s['of']} runs)" if s["n"] < s.get("of", 0) else ""  # e.g. no slew landed
    return f"{fmt.format(scale * s['mean'])} ± {fmt.format(scale * s['std'])}{part}"


def table_markdown(result: dict[str, Any]) -> str:
    """The study's table (mean ± std over seeds) as Markdown."""
    head = (
        "| method | seeds | env steps | success @0.25 deg (%) | success @1 deg (%) | return | slew / bound "
        "| PD on its designs: success @0.25 deg (%) | PD return | modules | actuators | mirror planes "
        "| products / principal | CoM offset (modules) |"
    )
    lines = [head, "|" + "---|" * 14]
    for label, a in result["algorithms"].items():
        p, d, m = a["policy"], a["pd_on_designs"], a["design_means"]
        unfinished = f" ({a['finished']} finished)" if a["finished"] < len(a["seeds"]) else ""
        lines.append(
            f"| {label} | {', '.join(map(str, a['seeds']))}{unfinished} | {max(a['env_steps']):,} | "
            f"{_pm(p['success_0.25'], 100)} | {_pm(p['success_1'], 100)} | {_pm(p['return'])} | "
            f"{_pm(p['slew_ratio'], fmt='{:.2f}')} | {_pm(d['success_0.25'], 100)} | {_pm(d['return'])} | "
            f"{_pm(m['modules'])} | {_pm(m['actuators'])} | {_pm(m['mirror_planes'])} | "
            f"{_pm(m['products_of_inertia_ratio'], fmt='{:.3f}')} | {_pm(m['com_offset_modules'], fmt='{:.2f}')} |"
        )
    conds = [(label, a["conditions"]) for label, a in result["algorithms"].items() if a.get("conditions")]
    if conds:
        lines += [
            "",
            "Flight conditions (docs/robustness.md), success at the mission's tolerance (%), mean ± std over seeds:",
            "",
            "| method | condition | policy | PD on its designs | policy violations | PD violations |",
            "|---|---|---|---|---|---|",
        ]
        for label, table in conds:
            for name, row in table.items():
                p, d = row["policy"], row["pd"]
                lines.append(
                    f"| {label} | {name} | {_pm(p['success'], 100)} | {_pm(d['success'], 100)} | "
                    f"{_pm(p['violations'])} | {_pm(d['violations'])} |"
                )
    return "\n".join(lines) + "\n"


def _png(fig) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def curves_png(result: dict[str, Any], title: str) -> bytes:
    """Mean return and success rate against env steps, mean ± std over seeds (shaded)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), dpi=100)
    for label, a in result["algorithms"].items():
        for ax, key, scale in zip(axes, ("mean_return", "success_rate"), (1.0, 100.0)):
            c = a["curves"][key]
            x, m, s = np.array(c["env_steps"]), scale * np.array(c["mean"]), scale * np.array(c["std"])
            (line,) = ax.step(x, m, where="post", label=f"{label} ({len(c['seeds'])} seeds)")
            ax.fill_between(x, m - s, m + s, step="post", alpha=0.25, color=line.get_color())
    axes[0].set_ylabel("evaluation return")
    axes[1].set_ylabel("success at the mission's tolerance (%)")
    axes[1].set_ylim(-5, 105)
    for ax in axes:
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{title}; mean ± std over seeds (RL: the policy's evaluation, GA: best design so far)", fontsize=9)
    fig.tight_layout()
    return _png(fig)


def design_png(design: DesignReport, title: str) -> bytes:
    """The satellite as voxels: structure grey, actuators orange."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = design.array
    colors = np.empty(g.shape, dtype=object)
    colors[g >= ACTUATOR] = "#f28e2b"
    colors[(g != EMPTY) & (g < ACTUATOR)] = "#bab0ac"
    fig = plt.figure(figsize=(3.6, 3.6), dpi=100)
    ax = fig.add_subplot(projection="3d")
    ax.voxels(g != EMPTY, facecolors=colors, edgecolor="k", linewidth=0.4)
    n = g.shape[0]
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(0, n)
    ax.set_box_aspect((1, 1, 1))
    ax.set(xticklabels=[], yticklabels=[], zticklabels=[])
    ax.set_title(title, fontsize=9)
    return _png(fig)


def report_files(runs: list[SavedRun]) -> tuple[dict[str, bytes], dict[str, Any]]:
    """The files `modsat report` writes: study.json, table.md, curves.png, designs/*.png."""
    result = study(runs)
    by_path = {r.path: r for r in runs}
    files: dict[str, bytes] = {}
    for label, a in result["algorithms"].items():
        slug = "".join(c if c.isalnum() else "-" for c in label.lower()).strip("-")
        for d in a["designs"]:
            name, k = f"designs/{slug}-seed{d['seed']}.png", 1
            while name in files:  # two runs of one method and seed (e.g. two budgets)
                k += 1
                name = f"designs/{slug}-seed{d['seed']}-{k}.png"
            design = by_path[d["run"]].design
            assert design is not None  # only runs with a design are in "designs"
            files[name] = design_png(design, f"{label}, seed {d['seed']}: {describe(d['modules'], d['actuators'])}")
            d["png"] = name
    n = result["grid_size"]
    title = f"{n}x{n}x{n}: {runs[0].spec.mission.tolerance_deg:g} deg tolerance"
    files["study.json"] = json.dumps(result, indent=1).encode()
    files["table.md"] = table_markdown(result).encode()
    files["curves.png"] = curves_png(result, title)
    return files, result
