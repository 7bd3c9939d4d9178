"""``modsat bench designs``' flights: a design that misses a slew is named with what sets how it flies."""

from __future__ import annotations

import numpy as np
import torch

from modsat_core.bench.designs import design_figures, fly_designs
from modsat_core.grid import ACTUATOR, STRUCTURE
from modsat_core.sim.pd import PDController
from modsat_core.spec.jobspec import JobSpec


def test_the_designs_that_miss_a_slew_are_named():
    spec = JobSpec.model_validate({"mission": {"episode_steps": 20}})
    one = np.zeros((3, 3, 3), dtype=np.int64)
    one[1, 1, 1] = ACTUATOR
    two = one.copy()
    two[1, 1, 0] = STRUCTURE

    def idle(sim):  # never turns: misses every slew
        return torch.zeros(sim.B, sim.K, 3, dtype=sim.dtype)

    out = fly_designs(idle, [one, two], 2, spec.mission, spec.modules, spec.evaluation)
    assert out["success_rate"] == 0.0 and [d["index"] for d in out["designs_missed"]] == [0, 1]
    named = out["designs_missed"][1]
    assert named["grid"] == two.tolist() and named["modules"] == 2 and named["wheels"] == 1
    assert named == {"index": 1, "success_rate": 0.0, "safety_violations": 0, **design_figures(two, spec.modules)}
    moments = named["principal_moments_kgm2"]
    assert moments == sorted(moments) and named["weakest_axis_accel_rad_s2"] > 0
    # a design that lands every slew (PD, the mission's whole episode) is not named
    long = spec.mission.model_copy(update={"episode_steps": 500})
    landed = fly_designs(PDController, [one], 2, long, spec.modules, spec.evaluation)
    assert landed["success_rate"] == 1.0 and landed["designs_missed"] == []
