"""What domain randomisation costs the first-order learner per update (docs/robustness.md):
`quick`'s updates, nominal and with `randomise` at the `combined` condition's magnitudes,
interleaved in one process so that both see the same machine load.

    OMP_NUM_THREADS=1 python docs/examples/randomise_overhead.py
"""

from __future__ import annotations

import json
import time

import torch

from modsat_core.spec.evaluation import STANDARD_CONDITIONS
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.presets import get_preset
from modsat_core.training.diffsim import DiffsimRun

RANDOMISE = STANDARD_CONDITIONS["combined"].changes()  # every quantity up to the `combined` condition


def main(updates: int = 12) -> None:
    torch.set_num_threads(1)
    base = get_preset("quick").model_dump(mode="json")
    runs = {
        "nominal": DiffsimRun(JobSpec.model_validate(base)),
        "randomised": DiffsimRun(JobSpec.model_validate({**base, "randomise": RANDOMISE})),
    }
    for run in runs.values():  # warm up
        for _ in range(3):
            run.update()
    spent = dict.fromkeys(runs, 0.0)
    for _ in range(updates):
        for name, run in runs.items():
            start = time.perf_counter()
            run.update()
            spent[name] += time.perf_counter() - start
    per_update = {k: v / updates for k, v in spent.items()}
    print(json.dumps({"per_update_s": per_update, "ratio": per_update["randomised"] / per_update["nominal"]}))


if __name__ == "__main__":
    main()
