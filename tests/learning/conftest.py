"""Tiny specs that train in seconds, for the mechanics of training (not its quality)."""

from __future__ import annotations

import pytest
import torch

from modsat_core.spec.jobspec import JobSpec
from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.train import train


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Every learning test trains on one torch thread, as the runs it asserts were measured
    (`modsat train` and the worker set it; an in-process `train()` does not). Without it a test
    inherits whatever an earlier test in its process left (`bench_update` sets one thread and
    does not restore it). Run first in a fresh xdist worker, the co-design test most likely
    trained on torch's default threads and missed (0.375 against 0.75 in one CI run)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def tiny_spec(**over) -> JobSpec:
    d = {
        "name": "tiny",
        "algorithm": "td3-codesign",
        "seed": 3,
        "design": {"grid_size": 2, "design_steps": 3},
        "modules": {"torque_scale_Nm": 0.05, "actuator_model": "reaction-wheel"},
        "mission": {"episode_steps": 12, "tolerance_deg": 1.0, "reward": {"safety_penalty_per_remaining_step": 1.0}},
        "training": {
            "total_env_steps": 480,
            "num_envs": 8,
            "hidden_sizes": [16, 16],
            "batch_size": 32,
            "buffer_size": 1000,
            "learning_starts": 96,
            "train_frequency": 4,
            "eval_every_steps": 160,
            "eval_episodes": 2,
            "checkpoint_every_steps": 160,
            "device": "cpu",
        },
        "ga": {"population_size": 4, "steps_per_design": 64},
        "evaluation": {"episodes": 3, "trajectories": 1},
    }
    for key, val in over.items():
        sec, _, name = key.partition("__")
        if name:
            d[sec][name] = val
        else:
            d[sec] = val
    return JobSpec.model_validate(d)


@pytest.fixture
def tiny():
    return tiny_spec


def first_checkpoint(spec: JobSpec) -> dict:
    """Train ``spec`` until its first checkpoint, stop there, and return that checkpoint as a
    resumed run reads it (through its bytes): ``train(spec, checkpoint=...)`` continues it."""
    ckpts: list[bytes] = []
    first = train(spec, on_checkpoint=lambda ck: ckpts.append(checkpoint_to_bytes(ck)), should_stop=lambda: bool(ckpts))
    assert first.stopped
    return checkpoint_from_bytes(ckpts[-1])
