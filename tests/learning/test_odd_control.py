"""`training.odd_control`: the control output is odd in the attitude error and rates, so a
pointed, still satellite gets exactly zero torque whatever the weights."""

from __future__ import annotations

import pytest
import torch

from modsat_core.agent.flat_networks import MLPActor
from modsat_core.agent.networks import NETWORKS, make_actor
from modsat_core.agent.policy_file import load_policy, new_actor, policy_bytes
from modsat_core.bench.control import bench_control
from modsat_core.codesign.features import N_FEATURES, PhysState, cell_observation, control_globals, mirror_control
from modsat_core.sim.gym_envs import reference_design
from modsat_core.sim.quaternion import canonical, normalize
from modsat_core.training.train import train

from .conftest import first_checkpoint, tiny_spec

IDENTITY = torch.tensor([1.0, 0.0, 0.0, 0.0])


def _attitudes(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return canonical(normalize(torch.randn(n, 4, generator=g))), torch.randn(n, 3, generator=g) * 0.05


def test_mirror_is_the_physical_mirror_and_its_own_inverse():
    q, w = _attitudes(64)
    g = control_globals(q, w, 0.1)
    inverse = torch.cat((q[:, :1], -q[:, 1:]), dim=-1)
    torch.testing.assert_close(mirror_control(g, 0), control_globals(inverse, -w, 0.1))
    torch.testing.assert_close(mirror_control(mirror_control(g, 0), 0), g)
    # only the target (q_v = 0, omega = 0) is left unchanged; the numbers around it are kept
    x = torch.cat((torch.randn(64, 5), g, torch.randn(64, 7)), dim=-1)
    m = mirror_control(x, 5)
    assert torch.equal(m[:, :5], x[:, :5]) and torch.equal(m[:, 25:], x[:, 25:])
    assert (m - x).abs().amax(-1).min() > 0
    target = control_globals(IDENTITY.expand(3, 4), torch.zeros(3, 3), 0.1)
    assert torch.equal(mirror_control(target, 0), target)


def test_flat_actor_is_odd_and_still_at_the_target():
    torch.manual_seed(0)
    actor = MLPActor(23, 3, [32, 32], mirror_at=0)
    plain = MLPActor(23, 3, [32, 32])
    q, w = _attitudes(32)
    h = torch.randn(32, 3)
    o = torch.cat((control_globals(q, w, 0.1), h), dim=-1)
    torch.testing.assert_close(actor(mirror_control(o, 0)), -actor(o))
    at_target = torch.cat((control_globals(IDENTITY.expand(32, 4), torch.zeros(32, 3), 0.1), h), dim=-1)
    assert torch.equal(actor(at_target), torch.zeros(32, 3))
    assert plain(at_target).abs().min() > 0  # without it the untrained actor pushes there
    assert actor(o).abs().min() > 0


def _cells(odd_rows: int = 6):
    """Observations of the full 3x3x3 cube: ``odd_rows`` flying at random attitudes with wheel
    momentum, two at the target, two designing."""
    n = odd_rows + 4
    q, w = _attitudes(n, seed=1)
    q[odd_rows : odd_rows + 2], w[odd_rows : odd_rows + 2] = IDENTITY, 0.0
    grids = torch.as_tensor(reference_design(3)).unsqueeze(0).repeat(n, 1, 1, 1)
    # the error quaternion is conj(q_TN) q_BN: with the target at the identity it is q_BN
    phys = PhysState(q, IDENTITY.expand(n, 4), w, torch.randn(n, 27, 3) * 0.1)
    step = torch.full((n,), 5)
    step[-2:] = 0
    return cell_observation(grids, step, 5, phys, 0.1), odd_rows


@pytest.mark.parametrize("network", NETWORKS)
def test_codesign_actors_odd_in_control_unchanged_in_design(network):
    obs, k = _cells()
    torch.manual_seed(0)
    actor = make_actor(network, N_FEATURES, [32, 32], odd_control=True)
    torch.manual_seed(0)
    plain = make_actor(network, N_FEATURES, [32, 32])
    a = actor.act(obs.x, obs.act_mask, obs.value_mask, obs.design)
    am = actor.act(mirror_control(obs.x), obs.act_mask, obs.value_mask, obs.design)
    torch.testing.assert_close(am[:k], -a[:k])
    assert a[:k].abs().amax() > 0.01
    assert torch.equal(a[k : k + 2], torch.zeros_like(a[k : k + 2]))  # pointed and still: no torque
    # design rows: the same design choices as the plain actor with the same weights
    torch.testing.assert_close(a[-2:], plain.act(obs.x, obs.act_mask, obs.value_mask, obs.design)[-2:])


def test_policy_file_keeps_the_odd_actor():
    spec = tiny_spec(design={"grid_size": 3}, training__odd_control=True)
    torch.manual_seed(0)
    actor = new_actor(spec)
    with torch.no_grad():  # weights that are not the constructor's, so the file must carry them
        for p in actor.parameters():
            p.add_(0.1)
    actor2, _, spec2 = load_policy(policy_bytes(actor, reference_design(3), spec))
    assert spec2.training.odd_control
    obs, k = _cells()
    with torch.no_grad():
        a = actor.act(obs.x, obs.act_mask, obs.value_mask, obs.design)
        torch.testing.assert_close(actor2.act(obs.x, obs.act_mask, obs.value_mask, obs.design), a)
        assert torch.equal(a[k : k + 2], torch.zeros_like(a[k : k + 2]))


def test_a_run_with_it_resumes_exactly_and_learns_something_else():
    spec = tiny_spec(training__network="set", training__odd_control=True, design__repair=True)
    full = train(spec)
    assert train(spec, checkpoint=first_checkpoint(spec)).curve == full.curve
    assert train(tiny_spec(training__network="set", design__repair=True)).curve != full.curve


def test_bench_control_flies_an_odd_actor():
    spec = tiny_spec(training__total_env_steps=400, training__odd_control=True)
    odd = bench_control(spec, eval_every=200)
    plain = bench_control(tiny_spec(training__total_env_steps=400), eval_every=200)
    assert [p["env_steps"] for p in odd["curve"]] == [200, 400]
    assert odd["curve"] != plain["curve"]
