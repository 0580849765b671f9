"""LeRobot statistics: exact against numpy where LeRobot is exact, LeRobot's approximation elsewhere."""

from __future__ import annotations

import numpy as np

from demo.interop.lerobot.stats import QUANTILES, STAT_NAMES, StatsAccumulator, histogram_stats, image_histogram, lowdim_stats, to_json


def test_lowdim_episode_stats_match_numpy() -> None:
    x = np.random.default_rng(0).normal(size=(50, 4)).astype(np.float32)
    s = lowdim_stats(x)
    assert list(to_json(s)) == list(STAT_NAMES)
    np.testing.assert_array_equal(s["min"], x.min(0))
    np.testing.assert_allclose(s["std"], x.astype(np.float64).std(0))
    for name, q in QUANTILES:
        np.testing.assert_allclose(s[name], np.quantile(x.astype(np.float64), q, axis=0))
    assert s["count"].tolist() == [50]
    assert lowdim_stats(np.arange(5.0))["mean"].shape == (1,)  # scalar features: one value


def test_image_histogram_quantiles_equal_numpy() -> None:
    images = np.random.default_rng(1).integers(0, 256, size=(7, 5, 6, 3), dtype=np.uint8)
    images[..., 2] //= 4  # a channel with a different range
    s = histogram_stats(image_histogram(images), len(images))
    pixels = images.reshape(-1, 3).astype(np.float64) / 255
    assert s["mean"].shape == (3, 1, 1) and s["count"].tolist() == [7]
    np.testing.assert_allclose(s["mean"].ravel(), pixels.mean(0))
    np.testing.assert_allclose(s["std"].ravel(), pixels.std(0))
    np.testing.assert_allclose(s["max"].ravel(), pixels.max(0))
    for name, q in QUANTILES:
        np.testing.assert_allclose(s[name].ravel(), np.quantile(pixels, q, axis=0), atol=1e-12)


def test_aggregate_is_exact_for_moments() -> None:
    rng = np.random.default_rng(2)
    episodes = [rng.normal(loc=i, size=(int(rng.integers(3, 30)), 2)) for i in range(5)]
    acc = StatsAccumulator(image=False)
    for ep in episodes:
        acc.add(ep)
    s = acc.result()
    allx = np.concatenate(episodes)
    np.testing.assert_allclose(s["mean"], allx.mean(0))
    np.testing.assert_allclose(s["std"], allx.std(0))
    np.testing.assert_array_equal(s["min"], allx.min(0))
    assert s["count"].tolist() == [len(allx)]
    assert np.all(s["q01"] <= s["q50"]) and np.all(s["q50"] <= s["q99"])
    images = [rng.integers(0, 256, size=(4, 3, 3, 3), dtype=np.uint8) for _ in range(3)]
    acc = StatsAccumulator(image=True)
    for im in images:
        acc.add(im)
    whole = histogram_stats(image_histogram(np.concatenate(images)), 12)
    for k in STAT_NAMES:
        np.testing.assert_array_equal(acc.result()[k], whole[k])
