"""Action distributions: the categorical floor, the ε schedule, Gaussians and continuous rescaling."""

import math

import numpy as np
import pytest
import torch

from racerlab.agent.distributions import (
    Categorical,
    DiagGaussian,
    TanhGaussian,
    epsilon_greedy,
    epsilon_schedule,
)
from racerlab.model import ContinuousActions


def test_categorical_probabilities_are_floored_at_1e8():
    logits = torch.tensor([[0.0, -100.0, 0.0]])  # softmax of the middle one is ~1e-44
    dist = Categorical(logits)
    assert dist.probs[0, 1].item() == pytest.approx(1e-8, rel=1e-6)
    assert dist.probs[0, 0].item() == pytest.approx(0.5, rel=1e-6)
    assert dist.log_prob(torch.tensor([1])).item() == pytest.approx(math.log(1e-8), rel=1e-6)
    # entropy uses the floored vector: 2·0.5·ln2 + 1e-8·ln(1e8)
    assert dist.entropy().item() == pytest.approx(math.log(2) + 1e-8 * math.log(1e8), rel=1e-6)


def test_categorical_sample_and_mode():
    dist = Categorical(torch.tensor([[0.0, 3.0, 0.0]]).repeat(2000, 1))
    gen = torch.Generator().manual_seed(0)
    counts = np.bincount(dist.sample(gen).numpy(), minlength=3) / 2000
    expected = np.exp([0, 3, 0]) / np.exp([0, 3, 0]).sum()
    assert np.allclose(counts, expected, atol=0.03)
    assert dist.mode()[0].item() == 1


@pytest.mark.parametrize("step, eps", [(0, 1.0), (5000, 0.525), (10000, 0.05), (25000, 0.05), (-3, 1.0)])
def test_epsilon_schedule_linear_from_one(step, eps):
    assert epsilon_schedule(step, final=0.05, steps=10000) == pytest.approx(eps)


def test_epsilon_schedule_zero_steps_is_final():
    assert epsilon_schedule(0, final=0.1, steps=0) == 0.1


def test_epsilon_greedy_extremes():
    dist = Categorical(torch.tensor([[0.0, 0.0, 5.0, 0.0]]).repeat(4000, 1))
    gen = torch.Generator().manual_seed(1)
    assert (epsilon_greedy(dist, 0.0, gen) == 2).all()
    uniform = np.bincount(epsilon_greedy(dist, 1.0, gen).numpy(), minlength=4) / 4000
    assert np.allclose(uniform, 0.25, atol=0.03)
    half = (epsilon_greedy(dist, 0.5, gen) == 2).float().mean().item()
    assert half == pytest.approx(0.5 + 0.5 / 4, abs=0.03)


def test_diag_gaussian_log_prob_entropy_and_clip():
    mean = torch.tensor([[0.0, 1.0]])
    dist = DiagGaussian(mean, torch.zeros(2))
    # standard normal at distance 0 and 1: -ln√(2π) - 0 and -ln√(2π) - 0.5
    assert dist.log_prob(torch.tensor([[0.0, 2.0]])).item() == pytest.approx(-math.log(2 * math.pi) - 0.5)
    assert dist.entropy().item() == pytest.approx(1.0 + math.log(2 * math.pi))
    assert DiagGaussian(mean, torch.tensor([10.0, -30.0])).log_std.tolist() == [[3.0, -20.0]]
    assert torch.equal(dist.mode(), mean)


def test_diag_gaussian_sample_is_unclipped():
    dist = DiagGaussian(torch.full((5000, 2), 0.9), torch.zeros(2))
    a = dist.sample(torch.Generator().manual_seed(0))
    assert a.max() > 2.0 and a.min() < -1.0  # not clipped to [-1, 1]: the env clips, the ratio must not
    assert a.mean().item() == pytest.approx(0.9, abs=0.05)


def test_tanh_gaussian_log_prob_has_the_jacobian():
    mean, log_std = torch.tensor([[0.3, -0.2]]), torch.tensor([[-0.5, 0.1]])
    dist = TanhGaussian(mean, log_std)
    a, logp = dist.rsample(torch.Generator().manual_seed(0))
    u = torch.atanh(a)
    base = torch.distributions.Normal(mean, log_std.exp()).log_prob(u)
    expected = (base - torch.log(1 - a.pow(2))).sum(-1)
    assert logp.item() == pytest.approx(expected.item(), abs=1e-4)
    assert TanhGaussian(mean, torch.full((1, 2), 5.0)).base.log_std.max().item() == 2.0
    assert torch.allclose(dist.mode(), torch.tanh(mean))


def test_tanh_gaussian_log_prob_is_finite_when_saturated():
    dist = TanhGaussian(torch.tensor([[30.0, -30.0]]), torch.zeros(1, 2))
    a, logp = dist.rsample(torch.Generator().manual_seed(0))
    assert torch.isfinite(logp).all() and (a.abs() <= 1).all()


def test_continuous_rescale_low_high_centre_and_clipping():
    space = ContinuousActions(-30.0, 30.0, 1.0, 3.0)
    steer, speed = space.rescale(np.array([[-1.0, -1.0], [1.0, 1.0], [0.0, 0.0], [-4.0, 2.5], [0.5, -0.5]]))
    assert steer.tolist() == [-30.0, 30.0, 0.0, -30.0, 15.0]
    assert speed.tolist() == [1.0, 3.0, 2.0, 3.0, 1.5]
