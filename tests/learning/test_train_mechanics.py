"""train(): outputs, determinism, stop + resume, and the replay-buffer memory bound."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from modsat_core.agent.networks import NETWORKS
from modsat_core.agent.policy_file import load_policy
from modsat_core.agent.td3 import ReplayBuffer
from modsat_core.grid import is_valid
from modsat_core.spec.evaluation import STANDARD_CONDITIONS
from modsat_core.training.checkpoint import checkpoint_from_bytes, checkpoint_to_bytes
from modsat_core.training.replay_layout import replay_buffer_bytes, replay_fields
from modsat_core.training.train import train

from .conftest import first_checkpoint, tiny_spec

EXPECTED = {"spec.json", "curve.json", "curve.png", "design.json", "evaluation.json", "trajectories.json", "policy.pt"}


@pytest.mark.parametrize("network", NETWORKS)
def test_run_writes_every_output(network):
    progress = []
    result = train(tiny_spec(training__network=network), on_progress=progress.append)
    files = result.artifacts()
    assert not result.stopped and result.env_steps == 480
    assert EXPECTED <= set(files)
    assert files["curve.png"][:8] == b"\x89PNG\r\n\x1a\n"
    curve = json.loads(files["curve.json"])["points"]
    assert [p["env_steps"] for p in curve] == [160, 320, 480]
    # success at the mission's tolerance and at 0.25 and 1 deg: never more slews at a tighter one
    for p in curve:
        assert 0.0 <= p["success_rate_at_0.25_deg"] <= p["success_rate_at_1_deg"] <= 1.0
    ev = json.loads(files["evaluation.json"])
    assert ev["policy"]["summary"]["episodes"] == 3
    design = json.loads(files["design.json"])
    actor, grid, spec = load_policy(files["policy.pt"])
    assert np.array_equal(grid, np.asarray(design["grid"])) and spec == tiny_spec(training__network=network)
    assert type(actor).__name__ == {"per-module": "CellActor", "set": "SetActor"}[network]
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


@pytest.mark.parametrize("network", NETWORKS)
def test_same_seed_same_curve_on_cpu(network):
    # Repaired designs fly, so that the curves carry returns that depend on the seed.
    a = train(tiny_spec(training__network=network, design__repair=True)).curve
    b = train(tiny_spec(training__network=network, design__repair=True)).curve
    assert a == b
    c = train(tiny_spec(seed=4, training__network=network, design__repair=True)).curve
    assert c != a


@pytest.mark.parametrize("network,explored", [(n, 1.0) for n in NETWORKS] + [("set", 0.5)])
def test_stop_and_resume_continues_from_the_checkpoint(network, explored):
    spec = tiny_spec(
        training__network=network,
        training__design_exploration_episodes=explored,
        training__exploration_noise_final=0.0,
        training__design_exploration_final=0.0,
    )
    full = train(spec)
    ckpts: list[bytes] = []
    seen = []

    def should_stop() -> bool:
        return bool(ckpts) and len(seen) > 0

    def on_ckpt(ck):
        ckpts.append(checkpoint_to_bytes(ck))

    def on_progress(p):
        if p["env_steps"] >= 200:
            seen.append(p["env_steps"])

    first = train(spec, on_progress=on_progress, on_checkpoint=on_ckpt, should_stop=should_stop)
    assert first.stopped and first.artifacts() == {}
    ck = checkpoint_from_bytes(ckpts[-1])
    saved = ck["env_steps"]
    assert 160 <= saved < 480
    resumed_progress = []
    second = train(spec, checkpoint=ck, on_progress=resumed_progress.append)
    assert not second.stopped and second.env_steps == 480
    assert min(p["env_steps"] for p in resumed_progress) > saved  # never goes back past the checkpoint
    # Everything (networks, optimisers, buffer, simulator, RNGs) was saved: the resumed run
    # is the uninterrupted run.
    assert second.curve == full.curve


def test_a_checkpoint_from_before_the_knobs_were_removed_resumes():
    """Checkpoints of their day hold each episode's noise draw ("noise_u", of the removed
    `exploration_noise_min`) and a replay column ``done`` (of the removed `n_step`): both ignored."""
    spec = tiny_spec(design__repair=True)
    ck = first_checkpoint(spec)
    ck["run"]["noise_u"] = torch.zeros(spec.training.num_envs)
    rows = ck["run"]["buffer"]["data"]["reward"].shape[0]
    ck["run"]["buffer"]["data"]["done"] = torch.zeros(rows, dtype=torch.bool)
    assert train(spec, checkpoint=ck).curve == train(spec).curve


def test_ga_run_stops_and_resumes():
    spec = tiny_spec(algorithm="ga", training__total_env_steps=320)
    ckpts: list[bytes] = []  # as the worker keeps them: bytes, read back with weights_only
    first = train(
        spec, on_checkpoint=lambda ck: ckpts.append(checkpoint_to_bytes(ck)), should_stop=lambda: len(ckpts) >= 3
    )
    assert first.stopped
    second = train(spec, checkpoint=checkpoint_from_bytes(ckpts[-1]))
    assert not second.stopped and second.env_steps == 320
    assert second.curve == train(spec).curve


def test_replay_buffer_of_5x5x5_for_5e5_transitions_is_under_2_GB():
    n = replay_buffer_bytes(5, 500_000)
    with_last = replay_buffer_bytes(5, 500_000, last_command=True)  # `training.observe_last_command`
    print(f"5x5x5 replay buffer, 5e5 transitions: {n / 2**30:.2f} GiB ({with_last / 2**30:.2f} with the last command)")
    assert n < with_last < 2 * 2**30
    small = ReplayBuffer(replay_fields(5), 100)  # the formula is what the buffer allocates
    assert small.nbytes == replay_buffer_bytes(5, 100)
    assert all(
        t.dtype in (torch.uint8, torch.int16, torch.float16, torch.float32, torch.bool) for t in small.data.values()
    )


def test_a_policy_file_from_before_the_network_choice_is_refused_with_a_reason():
    import io

    files = train(tiny_spec(training__total_env_steps=5)).artifacts()
    d = torch.load(io.BytesIO(files["policy.pt"]), weights_only=True)
    assert d["version"] == 2 and d["network"] == "per-module"
    old = {k: v for k, v in d.items() if k != "network"} | {"version": 1, "n_features": 47}
    buf = io.BytesIO()
    torch.save(old, buf)
    with pytest.raises(ValueError, match=r"older modsat.*train the run again"):
        load_policy(buf.getvalue())


def test_unexplored_episodes_grow_the_policy_s_own_design():
    """`design_exploration_episodes`: an episode drawn as unexplored grows exactly the design
    the deterministic actor grows (no swaps, no noise); explored ones differ. So do all
    episodes while the design is held with `design_exploration_after_release`."""
    from modsat_core.agent.policy import design_with
    from modsat_core.training.td3_trainer import TD3Run

    def grown(share: float, **kw) -> tuple[list, np.ndarray]:
        spec = tiny_spec(
            training__learning_starts=0,
            training__design_exploration=0.5,
            training__design_exploration_episodes=share,
            design__repair=True,
            **kw,
        )
        run = TD3Run(spec)
        for _ in range(spec.design.design_steps):
            run.env.step(run._act(run.env.observe()))
        return list(run.env.grids.numpy()), design_with(run.agent.actor, spec.design, spec.mission)

    grids, own = grown(0.0)
    assert all(np.array_equal(g, own) for g in grids)
    grids, own = grown(1.0)
    assert sum(not np.array_equal(g, own) for g in grids) >= len(grids) // 2
    # `design_exploration_after_release`: nothing is explored while the design is held, and
    # every share is explored again once it is released.
    held = {"training__design_exploration_after_release": True, "training__design_learning_starts": 10**6}
    grids, own = grown(1.0, **held)
    assert all(np.array_equal(g, own) for g in grids)
    grids, own = grown(1.0, training__design_exploration_after_release=True)
    assert sum(not np.array_equal(g, own) for g in grids) >= len(grids) // 2


def test_design_layers_hold_until_design_learning_starts():
    """The set network's design layers do not move before `design_learning_starts`; the control
    layers do; and after it the design layers learn."""
    from modsat_core.training.td3_trainer import TD3Run

    spec = tiny_spec(training__network="set", design__repair=True, training__design_learning_starts=10**6)
    run = TD3Run(spec)
    before = {k: v.clone() for k, v in run.agent.actor.state_dict().items()}
    run.run(lambda _p: None, lambda _c: None, lambda: False)
    after = run.agent.actor.state_dict()
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert moved and all(k.startswith("control.") for k in moved), sorted(moved)
    free = TD3Run(tiny_spec(training__network="set", design__repair=True))
    free.run(lambda _p: None, lambda _c: None, lambda: False)
    assert any(
        k.startswith("design.") and not torch.equal(before[k], v) for k, v in free.agent.actor.state_dict().items()
    )


def test_design_layers_hold_until_the_curve_lands_the_gate_share():
    """With `design_learning_after_success` the design layers stay held past
    `design_learning_starts` while no evaluation on the curve lands that share of its slews; one
    that does releases them, and a resumed run reads the gate's state back from the curve."""
    from modsat_core.training.td3_trainer import TD3Run

    spec = tiny_spec(training__network="set", design__repair=True, training__design_learning_after_success=0.5)
    run = TD3Run(spec)
    before = {k: v.clone() for k, v in run.agent.actor.state_dict().items()}
    run.run(lambda _p: None, lambda _c: None, lambda: False)
    # The tiny mission (12 steps, 0.05 N m) is not landed in 480 steps: the gate stays shut.
    assert run.curve and max(p["success_rate"] for p in run.curve) < 0.5
    assert not run.design_released()
    after = run.agent.actor.state_dict()
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert moved and all(k.startswith("control.") for k in moved), sorted(moved)

    landed = dict(run.curve[-1], success_rate=0.5)
    run.curve.append(landed)
    assert run.design_released()
    state = run.state_dict()
    resumed = TD3Run(spec)
    assert not resumed.design_released()
    resumed.load_state_dict(state)
    assert resumed.design_released()
    # The step count still applies: a gate met before `design_learning_starts` waits for it.
    late = TD3Run(
        tiny_spec(
            training__network="set",
            design__repair=True,
            training__design_learning_after_success=0.5,
            training__design_learning_starts=10**6,
        )
    )
    late.load_state_dict(state)
    assert not late.design_released()


def _design_gap(run) -> float:
    """Mean squared distance between the actor's design actions and the replay's, over the
    design rows of a fixed sample of the run's replay buffer."""
    from modsat_core.codesign.mdp import Compact, observe_compact

    b = run.buffer.sample(512, torch.Generator().manual_seed(0))
    obs = observe_compact(
        Compact.from_dict({k: b["obs_" + k] for k in Compact.FIELDS}),
        run.env.N,
        run.env.D,
        run.spec.mission.rate_limit_rad_s,
    )
    with torch.no_grad():
        gap, rows = run.agent.actor.imitation(obs, run.agent.actor(obs), b["action"].float())
    assert rows.sum() >= 16  # enough design rows in the sample to compare
    return float(gap[rows].mean())


def test_design_bc_keeps_the_design_head_near_the_flown_designs():
    """`design_bc` (TD3+BC on the design head) pulls the design actions towards the replay's:
    the same run without it ends further from them (0.35 against 0.25 when written; the
    replay's own exploration noise sets the floor)."""
    from modsat_core.training.td3_trainer import TD3Run

    gaps = {}
    for w in (0.0, 10.0):
        run = TD3Run(tiny_spec(training__network="set", design__repair=True, training__design_bc=w))
        run.run(lambda _p: None, lambda _c: None, lambda: False)
        gaps[w] = _design_gap(run)
    assert gaps[10.0] < 0.8 * gaps[0.0], gaps


#: Domain randomisation at the standard conditions' magnitudes (`randomise`, docs/robustness.md).
RANDOMISE = STANDARD_CONDITIONS["combined"].changes()


def test_td3_trains_under_domain_randomisation_and_resumes_exactly():
    """TD3's env draws each flight's conditions (its own stream): the run differs from the nominal
    one, and stop + resume (conditions, commands on their way, noise stream saved) is the straight run."""
    spec = tiny_spec(design__repair=True, randomise=RANDOMISE)
    straight = train(spec)
    assert straight.curve != train(tiny_spec(design__repair=True)).curve
    ck = first_checkpoint(spec)
    assert train(spec, checkpoint=ck).curve == straight.curve
