"""Learning benchmarks (not tests): whole training runs, timed, with their final evaluation.

``modsat bench learn``: one spec over several seeds -- wall time, env steps, updates, the
Monte-Carlo success at 0.25 and 1 deg, the median ratio of slew time to the eigenaxis
bound, and the PD baseline flown on the designed satellite over the same slews.

``modsat bench rl-vs-ga``: the same mission and env-step budget trained by RL co-design
and by the GA baseline, several seeds each; final Monte-Carlo return mean +/- std.
"""

from __future__ import annotations

import json
import os
import platform
import time
from typing import Any

import numpy as np
import torch

from modsat_core.spec.jobspec import JobSpec, parse_spec

KEYS = (
    "mean_return",
    "std_return",
    "success_rate",
    "success_rate_at_0.25_deg",
    "success_rate_at_1_deg",
    "safety_violations",
    "median_final_error_deg",
    "median_slew_time_ratio",
    "median_settling_time_s",
)


def _pick(summary: dict | None) -> dict | None:
    if summary is None:
        return None
    return {k: summary.get(k) for k in KEYS}


def run_one(spec: JobSpec, out_dir: str | None = None, log=None) -> dict:
    """Train ``spec`` to the end; the figures of its final evaluation and its cost."""
    from modsat_core.training.train import train

    t0 = time.monotonic()
    last = {}

    def progress(p: dict) -> None:
        last.update(p)
        if log is not None and p.get("eval"):
            e = p["eval"]
            log(
                f"  seed {spec.seed} {spec.algorithm}: {p['env_steps']:,} steps, {time.monotonic() - t0:,.0f} s, "
                f"eval return {e['mean_return']:.1f}, success {100 * e['success_rate']:.0f} %"
            )

    res = train(spec, on_progress=progress)
    wall = time.monotonic() - t0
    if out_dir is not None:
        d = os.path.join(out_dir, f"{spec.algorithm}-seed{spec.seed}")
        os.makedirs(d, exist_ok=True)
        for name, data in res.artifacts().items():
            with open(os.path.join(d, name), "wb") as fh:
                fh.write(data)
    s = res.summary
    return {
        "seed": spec.seed,
        "algorithm": spec.algorithm,
        "wall_s": round(wall, 1),
        "env_steps": res.env_steps,
        # A GA run's updates are per inner controller, not one count: not reported.
        "updates": last.get("updates") if spec.algorithm != "ga" else None,
        "env_steps_per_s": round(res.env_steps / wall, 1),
        "design": s["design"],
        "designs_evaluated": s.get("designs_evaluated"),
        "policy": _pick(s["policy"]),
        "pd_baseline": _pick(s["pd_baseline"]),
    }


def _stats(values: list[float]) -> dict:
    a = np.asarray([v for v in values if v is not None], dtype=float)
    if len(a) == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(a.mean()), "std": float(a.std(ddof=1)) if len(a) > 1 else 0.0, "n": len(a)}


def _environment() -> dict:
    return {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpus": os.cpu_count(),
        "machine": platform.machine(),
        "cuda": torch.cuda.is_available(),
    }


def _seeded(spec: JobSpec, seeds: list[int]) -> list[JobSpec]:
    """``spec`` once per seed, each re-validated (all before any run starts: a bad seed fails at once)."""
    return [parse_spec(spec.model_copy(update={"seed": seed}).model_dump_json()) for seed in seeds]


def bench_learn(spec: JobSpec, seeds: list[int], out_dir: str | None = None, log=None) -> dict:
    runs = [run_one(s, out_dir, log) for s in _seeded(spec, seeds)]
    agg = {
        k: _stats([r["policy"][k] for r in runs])
        for k in ("mean_return", "success_rate_at_0.25_deg", "success_rate_at_1_deg")
    }
    agg["wall_s"] = _stats([r["wall_s"] for r in runs])
    return {
        "benchmark": "learn",
        "spec": spec.model_dump(mode="json"),
        "environment": _environment(),
        "runs": runs,
        "aggregate": agg,
    }


def ga_spec_like(rl: JobSpec, population: int, steps_per_design: int) -> JobSpec:
    """The GA run matching an RL spec: same mission, modules, TD3 settings and budget."""
    d = rl.model_dump(mode="json")
    d["algorithm"] = "ga"
    d["name"] = (rl.name or "run") + "-ga"
    d["ga"] = {**d["ga"], "population_size": population, "steps_per_design": steps_per_design}
    return parse_spec(json.dumps(d))


def bench_rl_vs_ga(
    rl: JobSpec, seeds: list[int], population: int, steps_per_design: int, out_dir: str | None = None, log=None
) -> dict:
    ga = ga_spec_like(rl, population, steps_per_design)
    out: dict[str, Any] = {
        "benchmark": "rl-vs-ga",
        "environment": _environment(),
        "env_step_budget": rl.training.total_env_steps,
        "rl_spec": rl.model_dump(mode="json"),
        "ga": ga.ga.model_dump(mode="json"),
        "runs": {"rl": [], "ga": []},
    }
    for rl_s, ga_s in zip(_seeded(rl, seeds), _seeded(ga, seeds)):
        out["runs"]["rl"].append(run_one(rl_s, out_dir, log))
        out["runs"]["ga"].append(run_one(ga_s, out_dir, log))
    for key in ("rl", "ga"):
        out[key] = {
            k: _stats([r["policy"][k] for r in out["runs"][key]])
            for k in ("mean_return", "success_rate", "median_final_error_deg")
        }
    return out
