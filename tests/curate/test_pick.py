"""Curation on real scripted `pick` episodes from the simulator, with known flaws added to copies:
the signals must work at the scales of actual robot data, not only on synthetic reaches."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.curate.curate import analyse
from demo.store import EpisodeStore

pytestmark = pytest.mark.slow  # collects pick episodes: ~9 s

pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def pick_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.collect.scripted import CollectConfig, collect_scripted

    tmp = tmp_path_factory.mktemp("pick")
    collect_scripted(CollectConfig(task="pick", episodes=8, seed=11), tmp / "expert.zarr")
    out = tmp / "flawed.zarr"
    rng = np.random.default_rng(0)
    with EpisodeStore.open(tmp / "expert.zarr") as src:
        episodes = [(src.read_episode(i), {k: v for k, v in src.episode_info(i).items() if k in ("success", "seed", "operator", "source")})
                    for i in range(src.num_episodes)]
        meta = src.meta
    flawed = []
    # 8: a shaky copy of episode 0 (0.03 rad white noise on the arm targets)
    data, info = episodes[0]
    shaky = {k: v.copy() for k, v in data.items()}
    shaky["action"][:, :7] += rng.normal(0, 0.03, shaky["action"][:, :7].shape).astype(np.float32)
    flawed.append((shaky, {**info, "seed": 1000}))
    # 9: episode 1 with a 2 s idle start (its first frame held for 40 frames)
    data, info = episodes[1]
    flawed.append(({k: np.concatenate([np.repeat(v[:1], 40, axis=0), v]) for k, v in data.items()}, {**info, "seed": 1001}))
    # 10: an exact duplicate of episode 2
    flawed.append(({k: v.copy() for k, v in episodes[2][0].items()}, {**episodes[2][1], "seed": 1002}))
    # 11: episode 3 recorded as a failure
    flawed.append(({k: v.copy() for k, v in episodes[3][0].items()}, {**episodes[3][1], "success": False, "seed": 1003}))
    with EpisodeStore.create(out, meta) as store:
        store.append_episodes(episodes + flawed)
    return out


def test_known_flaws_on_pick_episodes(pick_store: Path) -> None:
    with EpisodeStore.open(pick_store) as store:
        c = analyse(store)
    assert c.kept[:8].all(), c.reasons[:8]  # the clean expert episodes stay
    assert c.codes[8] == ["jerky"], c.reasons[8]
    assert c.signals["jerk"][8] > 5 * c.signals["jerk"][:8].max()
    assert c.kept[9] and c.trimmed[9]  # a 2 s idle start is cut, the episode kept
    assert 1.9 <= c.signals["idle_start_s"][9] <= 2.3
    assert c.trim[9, 0] == round(c.signals["idle_start_s"][9] * store.meta.fps) - 2
    assert c.codes[10] == ["duplicate"] and c.signals["dup_of"][10] == 2
    assert c.codes[11] == ["failed", "duplicate"] and c.signals["dup_of"][11] == 3  # a failed copy of 3
    assert np.isfinite(c.signals["consistency"][:8]).all()
