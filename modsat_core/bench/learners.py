"""``modsat bench learners``: the first-order learner, TD3 and PD on the same designs and slews.

For each design (the full 3x3x3 cube with its centre actuator, and an asymmetric 3-actuator
design whose products of inertia are not zero) and each seed, on the `cpu-3x3x3` mission:

- ``diffsim``: a `diffsim-control` run (the spec's `diffsim` defaults, ``steps`` env steps),
  timed from its start to the start of its final evaluation (its 4 learning-curve points, on 8
  slews each, are inside that time; the best of them is kept, as in any run);
- ``td3``: flat-MLP TD3 (`modsat bench control`, the `cpu-3x3x3` recipe's settings) trained for
  the same wall time as that diffsim run, its best curve snapshot;
- ``pd``: the PD baseline, once per design.

Every row is flown on the same 100 held-out slews (``evaluation.seed``) in float64 on the
mission's own physics. One torch thread. The output is a JSON list of rows.
"""

from __future__ import annotations

import json
import platform
import time
from typing import Any

import numpy as np
import torch

from modsat_core.grid import ACTUATOR, STRUCTURE
from modsat_core.sim.gym_envs import reference_design
from modsat_core.spec.jobspec import JobSpec, parse_spec
from modsat_core.spec.presets import get_preset

#: Env steps of a diffsim row: 120 updates of 256 slews x 32 steps (docs/diffsim.md: on the PD
#: base every seed of both designs settles sooner than PD after 120).
DIFFSIM_STEPS = 120 * 256 * 32


def three_actuator_design() -> np.ndarray:
    """A 3x3x3 design of 16 modules, 3 of them wheel units, none at the centre: a full bottom
    layer, a column and an arm above it (off-diagonal inertia, an off-centre mass centre)."""
    g = np.zeros((3, 3, 3), dtype=np.int8)
    g[0, :, :] = STRUCTURE
    g[1, 1, :] = STRUCTURE
    g[2, 1, 1:] = STRUCTURE
    g[1, 0, 1] = STRUCTURE
    g[1, 2, 2] = STRUCTURE
    for cell in ((0, 0, 0), (1, 1, 2), (2, 1, 2)):
        g[cell] = ACTUATOR
    return g


DESIGNS = {"cube": lambda: reference_design(3), "three-actuator": three_actuator_design}


def _spec(algorithm: str, grid: np.ndarray, seed: int, steps: int) -> JobSpec:
    d = get_preset("cpu-3x3x3").model_dump(mode="json")
    d.update(algorithm=algorithm, seed=seed, name=f"bench-{algorithm}")
    d["design"]["fixed_design"] = grid.tolist()
    d["training"].update(total_env_steps=steps, select_top_k=1, checkpoint_every_steps=10**9)
    if algorithm == "diffsim-control":  # 4 curve points on 8 slews each (the best is kept), inside train_s
        d["training"].update(eval_every_steps=max(1, steps // 4), eval_episodes=8)
    else:  # TD3 on the flat state, as `modsat bench control` trains it: the recipe's widths and rates
        d["training"].update(hidden_sizes=[256, 256])
    return parse_spec(d)  # a SpecError naming the field (a seed out of range, a budget too large)


def _row(learner: str, design: str, seed: int | None, train_s: float | None, s: dict, pd: dict) -> dict[str, Any]:
    return {
        "learner": learner,
        "design": design,
        "seed": seed,
        "train_s": None if train_s is None else round(train_s, 1),
        "success_rate_at_0.25_deg": s["success_rate_at_0.25_deg"],
        "median_settling_time_s": s["median_settling_time_s"],
        "pd_median_settling_time_s": pd["median_settling_time_s"],
        "safety_violations": s["safety_violations"],
        "median_final_error_deg": s["median_final_error_deg"],
        "max_peak_rate_rad_s": s.get("max_peak_rate_rad_s"),
    }


def timed_train(spec: JobSpec) -> tuple[dict[str, bytes], float, float]:
    """Train ``spec``: its files, the seconds from its start to the start of its final evaluation
    (``train_s``, the curve's points included), and the whole wall time."""
    from modsat_core.training.train import train

    t0 = time.monotonic()
    ended: list[float] = []

    def progress(p: dict) -> None:
        if p.get("phase") == "evaluating" and not ended:
            ended.append(time.monotonic() - t0)

    files = train(spec, on_progress=progress).artifacts()
    wall = time.monotonic() - t0
    return files, (ended[0] if ended else wall), wall


def diffsim_row(design: str, spec: JobSpec) -> tuple[dict, dict]:
    """A diffsim row of ``spec`` (see :func:`_spec`) and the PD summary on the same slews."""
    files, train_s, _wall = timed_train(spec)
    ev = json.loads(files["evaluation.json"])
    pd = ev["pd_baseline"]["summary"]
    return _row("diffsim", design, spec.seed, train_s, ev["policy"]["summary"], pd), pd


def td3_row(design: str, spec: JobSpec, wall_s: float, pd: dict) -> dict:
    """A TD3 row of ``spec`` trained for ``wall_s`` seconds (flat MLP, `modsat bench control`)."""
    from modsat_core.bench.control import bench_control

    # the flat network has neither the last command nor the curriculum (TD3Run says so where a spec asks)
    flat = spec.training.model_copy(update={"observe_last_command": False, "randomise_after_success": None})
    spec = spec.model_copy(update={"training": flat})
    out = bench_control(spec, eval_every=10**9, max_wall_s=wall_s)  # evaluated once, at the end
    row = _row("td3", design, spec.seed, out["train_s"], out["best"], pd)
    row["env_steps"] = out["env_steps"]
    return row


def bench_learners(
    seeds: list[int], designs: list[str], steps: int = DIFFSIM_STEPS, td3: bool = True, log=None
) -> list[dict]:
    """Rows for every design and seed (see the module docstring), each naming the CPU it ran on."""
    torch.set_num_threads(1)
    cpu = {"cpu": _cpu_model(), "torch": torch.__version__}
    rows: list[dict] = []

    def add(row: dict) -> None:
        rows.append({**row, **cpu})
        if log:
            log(rows[-1])

    # Every spec validated before any run starts: a bad seed or budget fails at once, not an hour in.
    specs = {
        (design, seed): (
            _spec("diffsim-control", DESIGNS[design](), seed, steps),
            _spec("td3-control", DESIGNS[design](), seed, 10**9),
        )
        for design in designs
        for seed in seeds
    }
    for design in designs:
        pd: dict | None = None
        for seed in seeds:
            diffsim_spec, td3_spec = specs[design, seed]
            row, pd = diffsim_row(design, diffsim_spec)
            add(row)
            if td3:
                add(td3_row(design, td3_spec, row["train_s"], pd))
        if pd is not None:
            add(_row("pd", design, None, None, pd, pd))
    return rows


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            return next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), platform.processor())
    except OSError:
        return platform.processor()
