"""Jerk on constructed episodes: a jittery one, a smooth one, gripper steps, the recording rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.curate import synthetic
from demo.curate.frames import load_frames
from demo.curate.signals import jerk
from demo.store import ActionSpec, EpisodeStore, StoreMeta


def jerk_of(tmp_path: Path, flaws: list[synthetic.Flaws], fps: float = 20.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    episodes = [(synthetic.episode(rng, f, fps=fps, duration_s=3.0), {}) for f in flaws]
    path = synthetic.write_store(tmp_path / f"s{fps:g}.zarr", episodes, fps=fps)
    with EpisodeStore.open(path) as store:
        return jerk.compute(load_frames(store))["jerk"]


def test_jittery_episode_has_far_more_jerk(tmp_path: Path) -> None:
    j = jerk_of(tmp_path, [synthetic.Flaws(), synthetic.Flaws(), synthetic.Flaws(jitter=0.02), synthetic.Flaws(jitter=0.005)])
    assert j[2] > 100 * max(j[0], j[1])
    assert j[3] > 10 * max(j[0], j[1])
    # White noise: jerk grows in proportion to its amplitude (4x the noise, about 4x the jerk).
    assert j[2] / j[3] == pytest.approx(4.0, rel=0.35)


def test_smooth_reach_matches_the_analytic_jerk(tmp_path: Path) -> None:
    # A minimum-jerk move of amplitude A over T seconds has RMS jerk 60*A/T^3 * rms(1 - 6t + 6t^2)
    # = 60*A/T^3 * sqrt(1/5); with the store's range equal to the amplitude, A = 1 range.
    j = jerk_of(tmp_path, [synthetic.Flaws(), synthetic.Flaws()], fps=100.0)
    assert 0.3 < j[0] / (60 / 3.0**3 * np.sqrt(0.2)) < 1.5


def test_gripper_steps_do_not_count(tmp_path: Path) -> None:
    with_steps = jerk_of(tmp_path, [synthetic.Flaws(), synthetic.Flaws()])
    # The synthetic gripper closes with a 0 -> 1 step mid-episode; it must not dominate the jerk.
    assert with_steps.max() < 5.0


def test_fps_independent_for_noise(tmp_path: Path) -> None:
    # The same per-step noise amplitude reads the same jerk at 20 and 100 fps: jerk is measured over 50 ms.
    j20 = jerk_of(tmp_path, [synthetic.Flaws(jitter=0.01)] * 2, fps=20.0)
    j100 = jerk_of(tmp_path, [synthetic.Flaws(jitter=0.01)] * 2, fps=100.0)
    assert j20.mean() == pytest.approx(j100.mean(), rel=0.5)


def test_delta_actions_use_the_integrated_trajectory(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    base = synthetic.meta()
    meta = StoreMeta(fps=20.0, features={k: v for k, v in base.features.items() if k != "action"},
                     action=ActionSpec("joint_vel", base.action.names, ("rad/s",) * 7 + ("1",)))
    episodes = []
    for flaws in (synthetic.Flaws(), synthetic.Flaws(jitter=0.02)):
        data = synthetic.episode(rng, flaws)
        data["action"][:, :7] = np.diff(np.concatenate([data["obs.joint_pos"][:1], data["action"][:, :7]]), axis=0) * 20.0
        episodes.append((data, {}))
    with EpisodeStore.create(tmp_path / "d.zarr", meta) as store:
        store.append_episodes(episodes)
        fd = load_frames(store)
    assert fd.action_is_delta
    # The running sum restarts at each episode: the second episode's trajectory starts near 0.
    traj = fd.trajectory()
    assert np.abs(traj[fd.starts[1], :7]).max() < 1.0
    j = jerk.compute(fd)["jerk"]
    assert j[1] > 50 * j[0]
