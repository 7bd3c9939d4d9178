"""`training.exploration_noise_min`: each training episode draws its own exploration noise std."""

from __future__ import annotations

import math

import torch

from modsat_core.training.td3_trainer import TD3Run
from modsat_core.training.train import train

from .conftest import first_checkpoint, tiny_spec


def test_stds_are_log_uniform_between_the_floor_and_the_scheduled_noise():
    t = tiny_spec(training__exploration_noise=0.1, training__exploration_noise_min=0.001).training
    u = torch.tensor([0.0, 0.5, 1.0])
    assert torch.allclose(t.noise_stds(0, u), torch.tensor([0.001, 0.01, 0.1]), rtol=1e-5)
    # a million draws, log-uniform over two decades: half the episodes fly below 0.01
    many = t.noise_stds(0, torch.rand(10**6, generator=torch.Generator().manual_seed(0)))
    assert abs(float((many < 0.01).float().mean()) - 0.5) < 0.005
    assert float(many.min()) >= 0.001 and float(many.max()) <= 0.1
    # the schedule still applies on top: once it falls below the floor every episode has it
    late = tiny_spec(
        training__exploration_noise=0.1, training__exploration_noise_final=0.0, training__exploration_noise_min=0.001
    ).training
    assert torch.equal(late.noise_stds(480, u), torch.zeros(3))
    assert math.isclose(float(late.noise_stds(96 + 192, torch.tensor([1.0]))), 0.05, rel_tol=1e-6)
    # without a floor: one std for every episode
    plain = tiny_spec(training__exploration_noise=0.1).training
    assert torch.equal(plain.noise_stds(0, u), torch.full((3,), 0.1))


def test_each_episode_draws_its_std_when_it_starts():
    spec = tiny_spec(training__exploration_noise_min=0.001, design__repair=True)
    run = TD3Run(spec)
    u0 = run.noise_u.clone()
    assert len(set(u0.tolist())) == spec.training.num_envs  # one draw per episode, not one for all
    ended = torch.zeros(spec.training.num_envs, dtype=torch.bool)
    while not bool(ended.any()):
        before = run.noise_u.clone()
        st = run.env.step(run._act(run.env.observe()))
        run._draw_noise(st.done)
        # the episodes that ended drew again; the others kept theirs
        assert torch.equal(run.noise_u[~st.done], before[~st.done])
        assert not bool((run.noise_u[st.done] == before[st.done]).any())
        ended |= st.done
    # the noise each flying episode got is its own std (the first step after learning starts)
    assert float(spec.training.noise_stds(0, u0).std()) > 0.0


def test_without_a_floor_the_run_draws_nothing_extra():
    """Runs without `exploration_noise_min` keep their random streams: old results reproduce."""
    spec = tiny_spec()
    assert torch.equal(TD3Run(spec).noise_u, torch.zeros(spec.training.num_envs))
    assert train(spec).curve != train(tiny_spec(training__exploration_noise_min=0.001)).curve


def test_resume_keeps_every_episode_s_std():
    spec = tiny_spec(training__exploration_noise_min=0.001, design__repair=True)
    full = train(spec)
    ck = first_checkpoint(spec)
    assert ck["run"]["noise_u"].shape == (spec.training.num_envs,)
    assert train(spec, checkpoint=ck).curve == full.curve
