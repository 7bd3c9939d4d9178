"""train(): outputs, determinism, stop + resume, and the replay-buffer memory bound."""

from __future__ import annotations

import json

import numpy as np
import torch

from modsat_core.morphology import is_valid
from modsat_core.train import (
    checkpoint_from_bytes, checkpoint_to_bytes, load_policy, replay_buffer_bytes, replay_fields, train,
)
from modsat_core.td3 import ReplayBuffer

from .conftest import tiny_spec

EXPECTED = {"spec.json", "curve.json", "curve.png", "design.json", "evaluation.json", "trajectories.json",
            "policy.pt"}


def test_run_writes_every_output():
    progress = []
    result = train(tiny_spec(), on_progress=progress.append)
    files = result.artifacts()
    assert not result.stopped and result.env_steps == 480
    assert EXPECTED <= set(files)
    assert files["curve.png"][:8] == b"\x89PNG\r\n\x1a\n"
    curve = json.loads(files["curve.json"])["points"]
    assert [p["env_steps"] for p in curve] == [160, 320, 480]
    ev = json.loads(files["evaluation.json"])
    assert ev["policy"]["summary"]["episodes"] == 3
    design = json.loads(files["design.json"])
    actor, grid, spec = load_policy(files["policy.pt"])
    assert np.array_equal(grid, np.asarray(design["grid"])) and spec == tiny_spec()
    if design["valid"]:
        assert is_valid(grid) and "policy_export.pt" in files
        assert ev["pd_baseline"]["summary"]["episodes"] == 3
        assert len(json.loads(files["trajectories.json"])["policy"]) == 1
    steps = [p["env_steps"] for p in progress]
    assert steps == sorted(steps) and steps[-1] == 480 and progress[-1]["phase"] == "evaluating"
    assert any(p.get("eval") for p in progress)


def test_budget_is_never_exceeded():
    # 8 parallel episodes: 100 steps = 12 batches (96), the 13th would overrun.
    r = train(tiny_spec(training__total_env_steps=100, training__learning_starts=16))
    assert r.env_steps == 96 and r.curve[-1]["env_steps"] == 96
    r = train(tiny_spec(training__total_env_steps=5))  # less than one batch: untrained, evaluated
    assert r.env_steps == 0 and len(r.curve) == 1 and "policy.pt" in r.artifacts()


def test_same_seed_same_curve_on_cpu():
    a = train(tiny_spec()).curve
    b = train(tiny_spec()).curve
    assert a == b
    c = train(tiny_spec(seed=4)).curve
    assert c != a


def test_stop_and_resume_continues_from_the_checkpoint():
    full = train(tiny_spec())
    ckpts: list[bytes] = []
    seen = []

    def should_stop() -> bool:
        return bool(ckpts) and len(seen) > 0

    def on_ckpt(ck):
        ckpts.append(checkpoint_to_bytes(ck))

    def on_progress(p):
        if p["env_steps"] >= 200:
            seen.append(p["env_steps"])

    first = train(tiny_spec(), on_progress=on_progress, on_checkpoint=on_ckpt, should_stop=should_stop)
    assert first.stopped and first.artifacts() == {}
    ck = checkpoint_from_bytes(ckpts[-1])
    saved = ck["env_steps"]
    assert 160 <= saved < 480
    resumed_progress = []
    second = train(tiny_spec(), checkpoint=ck, on_progress=resumed_progress.append)
    assert not second.stopped and second.env_steps == 480
    assert min(p["env_steps"] for p in resumed_progress) > saved  # never goes back past the checkpoint
    # Everything (networks, optimisers, buffer, simulator, RNGs) was saved: the resumed run
    # is the uninterrupted run.
    assert second.curve == full.curve


def test_ga_run_stops_and_resumes():
    spec = tiny_spec(algorithm="ga", training__total_env_steps=320)
    ckpts = []
    first = train(spec, on_checkpoint=ckpts.append, should_stop=lambda: len(ckpts) >= 3)
    assert first.stopped
    second = train(spec, checkpoint=ckpts[-1])
    assert not second.stopped and second.env_steps == 320
    assert second.curve == train(spec).curve


def test_replay_buffer_of_5x5x5_for_5e5_transitions_is_under_2_GB():
    n = replay_buffer_bytes(5, 500_000)
    print(f"5x5x5 replay buffer, 5e5 transitions: {n / 2**30:.2f} GiB")
    assert n < 2 * 2**30
    small = ReplayBuffer(replay_fields(5), 100)  # the formula is what the buffer allocates
    assert small.nbytes == replay_buffer_bytes(5, 100)
    assert all(t.dtype in (torch.uint8, torch.int16, torch.float16, torch.float32, torch.bool)
               for t in small.data.values())
