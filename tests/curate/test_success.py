"""Outcome signals: success, success margin and time left before the horizon (near-miss)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.curate import synthetic
from demo.curate.signals import success
from demo.store import EpisodeStore, FeatureSpec, StoreMeta


def test_time_left_from_the_longest_failure(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    episodes = [
        (synthetic.episode(rng, duration_s=3.0), {"success": True}),
        (synthetic.episode(rng, duration_s=5.0), {"success": True}),
        (synthetic.episode(rng, duration_s=6.0), {"success": False}),  # ran to the horizon
    ]
    path = synthetic.write_store(tmp_path / "s.zarr", episodes)
    with EpisodeStore.open(path) as store:
        lengths = store.episode_lengths
        s = success.compute(store)
    np.testing.assert_array_equal(s["success"], [1.0, 1.0, 0.0])
    np.testing.assert_allclose(s["time_left_s"][:2], (lengths[2] - lengths[:2]) / 20.0)
    assert np.isnan(s["time_left_s"][2])
    assert np.isnan(s["margin"]).all()  # not recorded in this store


def test_horizon_and_margin_from_the_store(tmp_path: Path) -> None:
    base = synthetic.meta()
    meta = StoreMeta(
        fps=20.0,
        features={**{k: v for k, v in base.features.items() if k != "action"},
                  "info.success_margin": FeatureSpec((1,), "float32", "cube height above the success height", "m")},
        action=base.action,
        task={"name": "synthetic_reach", "horizon": 100},
    )
    rng = np.random.default_rng(0)
    with EpisodeStore.create(tmp_path / "s.zarr", meta) as store:
        for margin in (0.05, 0.001):
            data = synthetic.episode(rng)
            data["info.success_margin"] = np.linspace(-0.1, margin, len(data["action"]), dtype=np.float32)[:, None]
            store.append_episode(data, success=True)
        s = success.compute(store)
        np.testing.assert_allclose(s["margin"], [0.05, 0.001], rtol=1e-5)
        np.testing.assert_allclose(s["time_left_s"], (100 - store.episode_lengths) / 20.0)
        # A per-episode column wins over the per-frame feature.
        store.set_column("success_margin", [0.2, 0.3])
        np.testing.assert_allclose(success.compute(store)["margin"], [0.2, 0.3])
