"""DDPM schedule and DDPM/DDIM samplers, checked with the exact denoiser of a two-point distribution.

For data that is one of two points ``m_1, m_2`` with equal probability, ``E[x0 | x_t]`` is a softmax
-weighted mean of the points, so the samplers can be tested without training any network: forward
noising must reach N(0, I), and the reverse process must land back on the two points, both of them.
"""

from __future__ import annotations

import math

import pytest
import torch

from demo.policies.noise_scheduler import NoiseScheduler, squared_cosine_betas

MODES = torch.tensor([[0.6, -0.4, 0.2], [-0.6, 0.4, -0.2]])


def exact_denoiser(s: NoiseScheduler, modes: torch.Tensor = MODES):
    """The Bayes-optimal network output for the two-point distribution (per the scheduler's target)."""

    def denoise(x: torch.Tensor, t: int, k: int) -> torch.Tensor:
        ab = s.alpha_bar[t]
        d2 = ((x[:, None, :] - ab.sqrt() * modes[None]) ** 2).sum(-1)
        x0 = torch.softmax(-d2 / (2 * (1 - ab)), dim=1) @ modes
        return x0 if s.prediction == "sample" else (x - ab.sqrt() * x0) / (1 - ab).sqrt()

    return denoise


def mode_stats(x: torch.Tensor, modes: torch.Tensor = MODES) -> tuple[torch.Tensor, float]:
    dist = torch.cdist(x, modes)
    return dist.min(1).values, float((dist.argmin(1) == 0).float().mean())


def test_squared_cosine_schedule() -> None:
    betas = squared_cosine_betas(100)
    assert betas.shape == (100,) and float(betas.max()) <= 0.999 and float(betas.min()) > 0
    assert bool((betas[1:] >= betas[:-1]).all())  # noise added per step only grows
    s = NoiseScheduler(100)
    f = lambda u: math.cos((u + 0.008) / 1.008 * math.pi / 2) ** 2  # noqa: E731
    for t in (0, 10, 50, 90):  # alpha_bar follows the cosine law (below the 0.999 cap)
        assert float(s.alpha_bar[t]) == pytest.approx(f((t + 1) / 100) / f(0), rel=1e-4)
    assert float(s.alpha_bar[0]) > 0.999 and float(s.alpha_bar[-1]) < 1e-5


def test_forward_noising_reaches_standard_normal() -> None:
    s = NoiseScheduler(100)
    g = torch.Generator().manual_seed(0)
    x0 = MODES[torch.randint(0, 2, (20_000,), generator=g)]
    noise = torch.randn(x0.shape, generator=g)
    last = s.add_noise(x0, noise, torch.full((len(x0),), 99))
    assert last.mean(0).abs().max() < 0.03 and (last.std(0) - 1).abs().max() < 0.03
    first = s.add_noise(x0, noise, torch.zeros(len(x0), dtype=torch.long))
    assert (first - x0).abs().max() < 0.15  # t = 0 barely changes the data
    assert torch.equal(s.target(x0, noise), noise)
    assert torch.equal(NoiseScheduler(prediction="sample").target(x0, noise), x0)


def test_timesteps() -> None:
    s = NoiseScheduler(100)
    for n in (1, 3, 4, 8, 10, 50, 100):
        for spacing in ("quadratic", "linear"):
            ts = s.timesteps(n, "ddim", spacing)
            assert len(ts) == n and ts[0] == 99 and ts[-1] >= 0
            assert all(a > b for a, b in zip(ts, ts[1:]))
    assert s.timesteps(100, "ddpm") == list(range(99, -1, -1))
    assert s.timesteps(4, spacing="linear") == [99, 74, 49, 24]
    assert s.timesteps(4)[-1] < s.timesteps(4, spacing="linear")[-1]  # quadratic ends closer to clean
    with pytest.raises(ValueError):
        s.timesteps(0)
    with pytest.raises(ValueError):
        s.timesteps(101)


@pytest.mark.parametrize("prediction", ["epsilon", "sample"])
@pytest.mark.parametrize("sampler,steps", [("ddpm", 100), ("ddim", 10), ("ddim", 5)])
def test_reverse_process_recovers_both_modes(prediction: str, sampler: str, steps: int) -> None:
    s = NoiseScheduler(100, prediction)
    g = torch.Generator().manual_seed(1)
    x = s.sample(exact_denoiser(s), torch.randn(2000, 3, generator=g), steps, sampler, g)
    dist, frac_first = mode_stats(x)
    assert float(dist.quantile(0.99)) < 0.02, "samples must land on the modes, not between them"
    assert 0.45 < frac_first < 0.55, "both modes, in proportion"


def test_quadratic_spacing_beats_linear_at_few_steps() -> None:
    """Why quadratic is the default: with 4 DDIM steps, linear spacing leaves samples between modes."""
    s = NoiseScheduler(100)
    x_T = torch.randn(2000, 3, generator=torch.Generator().manual_seed(2))
    quad, _ = mode_stats(s.sample(exact_denoiser(s), x_T, 4, "ddim", spacing="quadratic"))
    lin, _ = mode_stats(s.sample(exact_denoiser(s), x_T, 4, "ddim", spacing="linear"))
    assert float((quad > 0.1).float().mean()) < 0.5 * float((lin > 0.1).float().mean())


def test_ddim_is_deterministic_and_ddpm_follows_its_generator() -> None:
    s = NoiseScheduler(100)
    x_T = torch.randn(64, 3, generator=torch.Generator().manual_seed(3))
    a = s.sample(exact_denoiser(s), x_T, 6, "ddim")
    b = s.sample(exact_denoiser(s), x_T.clone(), 6, "ddim", generator=torch.Generator().manual_seed(99))
    assert torch.equal(a, b)  # eta = 0: no noise is drawn
    c = s.sample(exact_denoiser(s), x_T, 20, "ddpm", torch.Generator().manual_seed(4))
    d = s.sample(exact_denoiser(s), x_T, 20, "ddpm", torch.Generator().manual_seed(4))
    e = s.sample(exact_denoiser(s), x_T, 20, "ddpm", torch.Generator().manual_seed(5))
    assert torch.equal(c, d) and not torch.equal(c, e)


def test_bad_settings() -> None:
    with pytest.raises(ValueError):
        NoiseScheduler(prediction="v")
    with pytest.raises(ValueError):
        NoiseScheduler(1)
    with pytest.raises(ValueError):
        NoiseScheduler().timesteps(4, sampler="euler")
