"""The conditional 1D UNet: shapes, FiLM conditioning, the cached-conditioning split, learning.

(Its traced inference path is checked against eager in tests/policies/test_diffusion.py.)
"""

from __future__ import annotations

import pytest
import torch
from torch.nn import functional as F

from demo.policies.unet1d import LARGE, SMALL, ConditionalUnet1D, count_parameters


pytestmark = pytest.mark.usefixtures("torch_one_thread")


def small_net(action_dim: int = 3, cond_dim: int = 10, channels=(16, 32, 64)) -> ConditionalUnet1D:
    torch.manual_seed(0)
    return ConditionalUnet1D(action_dim, cond_dim, channels, step_embed_dim=16).eval()


@pytest.mark.parametrize("horizon", [4, 8, 16, 32])
def test_shapes(horizon: int) -> None:
    net = small_net()
    x = torch.randn(5, horizon, 3)
    out = net(x, torch.randint(0, 100, (5,)), torch.randn(5, 10))
    assert out.shape == x.shape and torch.isfinite(out).all()


def test_output_depends_on_observation_and_timestep() -> None:
    net = small_net()
    x, t, obs = torch.randn(2, 16, 3), torch.tensor([10, 10]), torch.randn(2, 10)
    base = net(x, t, obs)
    assert (net(x, t, obs + 0.5) - base).abs().max() > 1e-3  # FiLM carries the observation
    assert (net(x, torch.tensor([80, 80]), obs) - base).abs().max() > 1e-3  # and the timestep
    # batch elements are independent (GroupNorm, not BatchNorm)
    assert torch.allclose(net(x[:1], t[:1], obs[:1]), base[:1], atol=1e-5)


def test_film_split_is_exact() -> None:
    """film_from_obs + film_from_step == the one Linear over Mish([step_embedding, obs])."""
    net = small_net()
    t, obs = torch.tensor([0, 37, 99]), torch.randn(3, 10)
    cond = torch.cat([net.step_encoder(t), obs], dim=1)
    full = F.linear(F.mish(cond), net.film.weight, net.film.bias)
    split = net.film_from_obs(obs) + net.film_from_step(t)
    assert torch.allclose(full, split, atol=1e-5)
    x = torch.randn(3, 16, 3)
    assert torch.allclose(net.denoise(x, full), net(x, t, obs), atol=1e-5)


@pytest.mark.slow
def test_it_learns_a_conditional_mapping() -> None:
    """A few hundred steps of regression: the FiLM path must carry the observation to the output."""
    net = small_net(action_dim=2, cond_dim=1, channels=(16, 32)).train()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    g = torch.Generator().manual_seed(0)
    ramp = torch.linspace(-1, 1, 8)

    def batch(n: int):
        c = torch.rand(n, 1, generator=g) * 2 - 1
        return c, torch.stack([c * ramp, -c * ramp], dim=-1)

    for _ in range(150):
        c, y = batch(64)
        loss = F.mse_loss(net(torch.zeros_like(y), torch.zeros(64, dtype=torch.long), c), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    c, y = batch(256)
    with torch.no_grad():
        err = F.mse_loss(net.eval()(torch.zeros_like(y), torch.zeros(256, dtype=torch.long), c), y)
    assert float(err) < 0.1 * float(y.var())


def test_sizes() -> None:
    small = ConditionalUnet1D(8, 56, SMALL)
    assert 2e6 < count_parameters(small) < 8e6
    assert LARGE == (256, 512, 1024)
    with pytest.raises(ValueError):
        ConditionalUnet1D(8, 56, (30, 60))  # not divisible by the 8 GroupNorm groups
