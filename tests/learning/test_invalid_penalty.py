"""An invalid design is never preferred: its penalty is below any valid design's return."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from modsat_core.codesign.mdp import CoDesignEnv, effective_invalid_penalty
from modsat_core.sim.mission import return_bounds
from modsat_core.spec.jobspec import JobSpec

from .conftest import tiny_spec


@settings(max_examples=200, deadline=None)
@given(
    penalty=st.floats(-1e6, 0.0),
    steps=st.integers(1, 5000),
    safety=st.floats(0.0, 1e4),
    per_remaining=st.floats(0.0, 100.0),
    no_progress=st.floats(0.0, 100.0),
)
def test_penalty_is_below_the_worst_valid_return(penalty, steps, safety, per_remaining, no_progress):
    spec = JobSpec.model_validate(
        {
            "design": {"invalid_penalty": penalty},
            "mission": {
                "episode_steps": steps,
                "reward": {
                    "safety_penalty": safety,
                    "safety_penalty_per_remaining_step": per_remaining,
                    "no_progress_penalty": no_progress,
                },
            },
        }
    )
    low, high = return_bounds(spec.mission)
    assert effective_invalid_penalty(spec.design, spec.mission) < low <= high


def _run_episodes(spec: JobSpec, design_action, control_action, episodes: int) -> list[dict]:
    """Drive the co-design env with fixed per-cell actions; collect finished episodes."""
    env = CoDesignEnv(spec, 4, seed=0)
    C = env.C
    done: list[dict] = []
    while len(done) < episodes:
        designing = (env.design_step < env.D).reshape(-1, 1, 1)
        a = torch.where(designing, design_action.expand(4, C, 3), control_action.expand(4, C, 3))
        done.extend(env.step(a).finished)
    return done


def test_worst_valid_episodes_still_beat_an_invalid_one():
    spec = tiny_spec(mission__episode_steps=30)
    pen = effective_invalid_penalty(spec.design, spec.mission)
    empty = torch.tensor([1.0, -1.0, -1.0])  # every cell chooses "empty": an invalid grid
    actuator = torch.tensor([-1.0, -1.0, 1.0])  # every cell an actuator: valid
    invalid = _run_episodes(spec, empty, torch.zeros(3), 4)
    assert all(not e["valid"] and e["return"] == pen for e in invalid)
    # Valid, flown as badly as possible: full torque (spins past the rate limit) and none.
    for control in (torch.ones(3), torch.zeros(3)):
        valid = _run_episodes(spec, actuator, control, 4)
        assert all(e["valid"] for e in valid)
        assert min(e["return"] for e in valid) > pen
    assert np.isfinite(pen)


def test_with_repair_every_grown_design_flies():
    from modsat_core.agent.networks import CellActor
    from modsat_core.agent.policy import design_with
    from modsat_core.codesign.features import N_FEATURES
    from modsat_core.grid import is_valid

    spec = tiny_spec(design__repair=True)
    env = CoDesignEnv(spec, 16, seed=0)
    gen = torch.Generator().manual_seed(0)
    finished = []
    for _ in range(3 * (spec.design.design_steps + spec.mission.episode_steps)):
        a = torch.rand((16, env.C, 3), generator=gen) * 2 - 1  # random designs: mostly invalid unrepaired
        finished += env.step(a).finished
    assert len(finished) >= 16
    assert all(r["valid"] and r["return"] > env.penalty for r in finished)
    torch.manual_seed(1)
    assert is_valid(design_with(CellActor(N_FEATURES, [16, 16]), spec.design, spec.mission))
