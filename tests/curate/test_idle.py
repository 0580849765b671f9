"""Idle signals on constructed episodes whose idle time is known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.curate import synthetic
from demo.curate.frames import load_frames
from demo.curate.signals import idle
from demo.store import EpisodeStore

FPS = 20.0


def frames_of(tmp_path: Path, flaws: list[synthetic.Flaws], seed: int = 0, fps: float = FPS):
    rng = np.random.default_rng(seed)
    episodes = [(synthetic.episode(rng, f, fps=fps), {"success": True}) for f in flaws]
    path = synthetic.write_store(tmp_path / "s.zarr", episodes, fps=fps)
    with EpisodeStore.open(path) as store:
        return load_frames(store)


def test_two_second_idle_start_is_measured_and_trimmed(tmp_path: Path) -> None:
    fd = frames_of(tmp_path, [synthetic.Flaws(), synthetic.Flaws(idle_start_s=2.0), synthetic.Flaws(idle_end_s=1.5)])
    s = idle.compute(fd, idle.IdleParams())
    # The minimum-jerk start is slow for a few frames, so the measured idle start is 2 s plus a little.
    assert 2.0 <= s["idle_start_s"][1] <= 2.5
    assert s["idle_start_s"][0] < 0.5 and s["idle_start_s"][2] < 0.5
    # The state settles after the command stops (joint positions one frame later, their finite-difference
    # velocities two), so the idle end reads up to two frames short.
    assert 1.4 <= s["idle_end_s"][2] <= 2.0
    # Trim keeps keep_start_s (0.1 s = 2 frames) of the idle start and keep_end_s of the idle end.
    assert s["trim_start"][1] == round(s["idle_start_s"][1] * FPS) - 2
    assert s["trim_start"][0] == 0 and s["trim_stop"][0] == fd.lengths[0]
    assert s["trim_stop"][2] == fd.lengths[2] - (round(s["idle_end_s"][2] * FPS) - 10)
    # An idle start/end is trimmed, not a pause: the pause fraction stays 0.
    np.testing.assert_allclose(s["pause_fraction"], 0.0)
    assert s["idle_fraction"][1] == pytest.approx(s["idle_start_s"][1] * FPS / fd.lengths[1])


def test_mid_episode_pause(tmp_path: Path) -> None:
    fd = frames_of(tmp_path, [synthetic.Flaws(), synthetic.Flaws(pause_s=1.5), synthetic.Flaws(pause_s=0.2)])
    s = idle.compute(fd, idle.IdleParams())
    assert 1.3 <= s["pause_max_s"][1] <= 1.8
    assert s["pause_s"][0] == 0.0
    assert s["pause_s"][2] == 0.0  # 0.2 s is shorter than min_run_s: settling, not a pause
    assert s["pause_fraction"][1] == pytest.approx(s["pause_s"][1] * FPS / fd.lengths[1], rel=1e-6)


def test_tremor_during_a_pause_still_reads_idle(tmp_path: Path) -> None:
    fd = frames_of(tmp_path, [synthetic.Flaws(), synthetic.Flaws(idle_start_s=2.0)])
    rng = np.random.default_rng(1)
    start = fd.starts[1]
    # Tremor of 0.05% of a joint's travel on the held command and the state.
    fd.action[start : start + 40, :7] += rng.normal(0, 2e-4, (40, 7)).astype(np.float32)
    fd.obs[start : start + 40, :7] += rng.normal(0, 2e-4, (40, 7)).astype(np.float32)
    smooth = idle.compute(fd, idle.IdleParams())
    raw = idle.compute(fd, idle.IdleParams(smooth_s=0.0))
    assert smooth["idle_start_s"][1] >= 1.9
    assert raw["idle_start_s"][1] < smooth["idle_start_s"][1]


def test_fully_idle_episode(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    still = synthetic.episode(rng)
    still = {k: np.repeat(v[:1], 40, axis=0) for k, v in still.items()}
    episodes = [(synthetic.episode(rng), {}), (still, {})]
    path = synthetic.write_store(tmp_path / "s.zarr", episodes)
    with EpisodeStore.open(path) as store:
        s = idle.compute(load_frames(store))
    assert s["idle_fraction"][1] == 1.0 and s["pause_fraction"][1] == 1.0
    assert s["trim_start"][1] == 0 and s["trim_stop"][1] == 40


def test_speed_is_independent_of_fps(tmp_path: Path) -> None:
    at20 = frames_of(tmp_path / "a", [synthetic.Flaws(idle_start_s=1.0)], fps=20.0)
    at100 = frames_of(tmp_path / "b", [synthetic.Flaws(idle_start_s=1.0)], fps=100.0)
    s20, s100 = idle.compute(at20), idle.compute(at100)
    assert s20["idle_start_s"][0] == pytest.approx(s100["idle_start_s"][0], abs=0.15)
