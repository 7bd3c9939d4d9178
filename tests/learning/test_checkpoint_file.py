"""Checkpoints are read with ``torch.load(weights_only=True)``: a checkpoint can be downloaded
from the API and handed back to ``modsat train --resume``, so a crafted pickle is refused;
checkpoints written before (a numpy array for the best design's grid) still read."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest
import torch

from modsat_core.training.checkpoint import CHECKPOINT_VERSION, checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.td3_trainer import TD3Run


class _Payload:
    """Runs a shell command when unpickled (what a hostile checkpoint would hold)."""

    def __reduce__(self):
        return (os.system, ("echo pwned > /dev/null",))


def test_a_crafted_pickle_checkpoint_is_refused_with_a_clear_error():
    buf = io.BytesIO()
    torch.save({"version": CHECKPOINT_VERSION, "run": {"payload": _Payload()}}, buf)
    with pytest.raises(ValueError, match=r"not a modsat checkpoint: it holds objects other than tensors"):
        checkpoint_from_bytes(buf.getvalue())
    buf = io.BytesIO()
    torch.save([1, 2], buf)
    with pytest.raises(ValueError, match=r"not a modsat checkpoint"):
        checkpoint_from_bytes(buf.getvalue())


def _run_with_a_best(tiny) -> TD3Run:
    run = TD3Run(tiny())
    grid = run.current_grid()
    run.kept = [
        {
            "mean_return": -1.0,
            "success_rate": 0.0,
            "env_steps": 0,
            "grid": np.asarray(grid, dtype=np.int64),
            "actor": {k: v.clone() for k, v in run.agent.actor.state_dict().items()},
        }
    ]
    return run


def test_a_checkpoint_is_plain_data_and_resumes_with_its_grid(tiny):
    run = _run_with_a_best(tiny)
    data = checkpoint_to_bytes({"version": CHECKPOINT_VERSION, "env_steps": 0, "run": run.state_dict()})
    raw = torch.load(io.BytesIO(data), weights_only=True)  # no numpy, no allow-list needed
    assert raw["run"]["kept"][0]["grid"] == run.kept[0]["grid"].tolist()
    again = TD3Run(tiny())
    again.load_state_dict(checkpoint_from_bytes(data)["run"])
    assert len(again.kept) == 1 and isinstance(again.kept[0]["grid"], np.ndarray)
    assert again.kept[0]["grid"].dtype == np.int64 and np.array_equal(again.kept[0]["grid"], run.kept[0]["grid"])
    assert again.rng.bit_generator.state == run.rng.bit_generator.state


def test_a_checkpoint_written_before_the_rule_still_reads(tiny):
    """Before, the best design's grid went into the checkpoint as a numpy array."""
    run = _run_with_a_best(tiny)
    buf = io.BytesIO()
    torch.save({"version": CHECKPOINT_VERSION, "env_steps": 0, "run": run.state_dict()}, buf)
    with pytest.raises(Exception, match="numpy"):
        torch.load(io.BytesIO(buf.getvalue()), weights_only=True)
    ck = checkpoint_from_bytes(buf.getvalue())
    again = TD3Run(tiny())
    again.load_state_dict(ck["run"])
    assert len(again.kept) == 1 and np.array_equal(again.kept[0]["grid"], run.kept[0]["grid"])


def test_a_checkpoint_from_before_select_top_k_reads_its_one_snapshot(tiny):
    """Before `training.select_top_k` a checkpoint held one snapshot under "best"."""
    run = _run_with_a_best(tiny)
    state = run.state_dict()
    state["best"] = state.pop("kept")[0]
    data = checkpoint_to_bytes({"version": CHECKPOINT_VERSION, "env_steps": 0, "run": state})
    again = TD3Run(tiny())
    again.load_state_dict(checkpoint_from_bytes(data)["run"])
    assert len(again.kept) == 1 and np.array_equal(again.kept[0]["grid"], run.kept[0]["grid"])
    state["best"] = None  # a run checkpointed before its first evaluation
    data = checkpoint_to_bytes({"version": CHECKPOINT_VERSION, "env_steps": 0, "run": state})
    again.load_state_dict(checkpoint_from_bytes(data)["run"])
    assert again.kept == []
