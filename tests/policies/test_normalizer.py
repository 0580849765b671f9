"""Min-max normalisation: [-1, 1] on the data, exact inverse, constant dimensions, safe state dict."""

from __future__ import annotations

import numpy as np
import torch

from demo.policies.normalizer import MinMaxNormalizer


def test_maps_data_range_to_minus_one_one_and_back() -> None:
    rng = np.random.default_rng(0)
    x = (rng.normal(size=(500, 4)) * [1, 10, 0.01, 100] + [0, 5, -3, 1000]).astype(np.float32)
    norm = MinMaxNormalizer.fit(x)
    y = norm.normalize(x)
    assert np.allclose(y.min(axis=0), -1, atol=1e-5) and np.allclose(y.max(axis=0), 1, atol=1e-5)
    assert np.allclose(norm.unnormalize(y), x, rtol=1e-5, atol=1e-3)
    t = torch.from_numpy(x)
    assert torch.allclose(norm.normalize_t(t), torch.from_numpy(y), atol=1e-5)
    assert torch.allclose(norm.unnormalize_t(norm.normalize_t(t)), t, rtol=1e-5, atol=1e-3)


def test_narrow_dimensions_are_widened_not_blown_up() -> None:
    rng = np.random.default_rng(2)
    x = np.stack([np.linspace(0, 1, 10), np.full(10, 0.04), 0.04 + 1e-4 * rng.normal(size=10)], axis=1)
    norm = MinMaxNormalizer.fit(x)
    y = norm.normalize(x)
    assert np.abs(y[:, 1]).max() < 1e-5 and np.abs(y[:, 2]).max() < 0.1
    # A deviation of 0.002 at test time (an idle gripper's jitter) stays a small input, not ~30.
    assert np.abs(norm.normalize(np.array([[0.5, 0.042, 0.042]]))[0, 1:]).max() < 0.5
    assert np.allclose(norm.unnormalize(y), x, atol=1e-6)


def test_state_dict_round_trip() -> None:
    norm = MinMaxNormalizer.fit(np.random.default_rng(1).normal(size=(50, 3)))
    back = MinMaxNormalizer.from_state_dict(norm.state_dict("n"), "n")
    assert np.array_equal(back.low, norm.low) and np.array_equal(back.high, norm.high)
