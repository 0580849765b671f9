"""Length outliers: robust z of log length, per task."""

from __future__ import annotations

import numpy as np

from demo.curate.signals import outliers


def test_long_and_short_episodes_stand_out() -> None:
    rng = np.random.default_rng(0)
    lengths = rng.integers(95, 106, 50).tolist() + [300, 30]
    z = outliers.compute(np.array(lengths))["length_z"]
    assert z[50] > 10 and z[51] < -10
    assert np.abs(z[:50]).max() < 3.5


def test_grouped_by_task() -> None:
    lengths = np.array([100, 102, 98, 101, 99, 103, 97, 100, 400, 405])
    tasks = np.array(["pick"] * 8 + ["stack"] * 2)
    z = outliers.compute(lengths, tasks)["length_z"]
    assert np.abs(z).max() < 3.5  # stack episodes are long for stack, not outliers
    z_pooled = outliers.compute(lengths)["length_z"]
    assert np.abs(z_pooled).max() > 3.5


def test_identical_lengths_use_the_floor() -> None:
    z = outliers.compute(np.array([100] * 20 + [101, 130]))["length_z"]
    assert abs(z[20]) < 1.0  # one frame longer is not an outlier
    assert z[21] > 3.5  # 30% longer is
