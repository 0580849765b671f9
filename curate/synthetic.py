"""Synthetic demonstrations whose quality is known by construction: for tests and the benchmark.

An episode is a 7-joint arm reaching from near its home pose to a goal-dependent joint target with a
minimum-jerk profile, then closing a gripper. The label ``action`` is the next joint target
(``joint_pos`` representation, rad) plus a 0/1 gripper command; ``obs.joint_pos`` follows the
action with one frame of lag, ``obs.joint_vel`` is its finite difference, ``obs.gripper`` the
gripper state and ``obs.goal`` the goal the target depends on (so that equal observations call for
equal actions, the property the consistency signal measures). The flaws a person adds can be
switched on one by one: an idle start/end, a mid-episode pause, jitter (white noise on the arm
targets), ``mirror`` (from the same start and goal as the others, heading the other way: a
contradicting demonstration) and ``reverse`` (the path driven backwards).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta

HOME = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
# Target = HOME + GOAL_TO_JOINTS @ goal: a fixed linear map, so the goal determines the motion.
GOAL_TO_JOINTS = np.array(
    [[1.2, 0.0, 0.0], [0.0, 0.8, 0.4], [0.5, 0.0, 0.6], [0.0, 1.0, -0.5], [0.3, -0.4, 0.0], [0.0, 0.6, 0.6], [-0.8, 0.0, 0.3]]
)
ARM_NAMES = tuple(f"joint{i + 1}" for i in range(7))


@dataclass(frozen=True)
class Flaws:
    """What an imperfect operator adds to the clean reach (all off by default)."""

    idle_start_s: float = 0.0
    idle_end_s: float = 0.0
    pause_s: float = 0.0  # one pause at 40% of the motion
    jitter: float = 0.0  # rad, std of white noise on the arm targets
    reverse: bool = False  # drive the path backwards: the others' positions, opposite velocities
    mirror: bool = False  # head for the mirror image of the goal's target: a contradicting demonstration
    speed: float = 1.0  # >1 faster, <1 slower


def meta(fps: float = 20.0, extra_obs: int = 0) -> StoreMeta:
    features = {
        "obs.joint_pos": FeatureSpec((7,), "float32", "arm joint angles", "rad", ARM_NAMES),
        "obs.joint_vel": FeatureSpec((7,), "float32", "arm joint velocities", "rad/s", ARM_NAMES),
        "obs.gripper": FeatureSpec((1,), "float32", "gripper closure, 0 open .. 1 closed", "1"),
        "obs.goal": FeatureSpec((3,), "float32", "goal the target depends on", "m"),
    }
    if extra_obs:
        features["obs.object"] = FeatureSpec((extra_obs,), "float32", "per-episode constant object features", "1")
    action = ActionSpec("joint_pos", (*ARM_NAMES, "gripper"), ("rad",) * 7 + ("1",), description="joint targets")
    return StoreMeta(fps=fps, features=features, action=action, task={"name": "synthetic_reach"})


def episode(
    rng: np.random.Generator, flaws: Flaws = Flaws(), *, fps: float = 20.0, duration_s: float = 3.0,
    goal: np.ndarray | None = None, extra_obs: int = 0,
) -> dict[str, np.ndarray]:
    """One episode as ``{key: array[T, ...]}`` for :meth:`EpisodeStore.append_episode`."""
    goal = rng.uniform(-0.5, 0.5, 3) if goal is None else np.asarray(goal, dtype=np.float64)
    q0 = HOME + rng.normal(0.0, 0.03, 7)
    q1 = HOME + (-1.0 if flaws.mirror else 1.0) * (GOAL_TO_JOINTS @ goal)
    if flaws.reverse:
        q0, q1 = q1, q0
    steps = max(4, int(round(duration_s / flaws.speed * fps)))
    tau = np.arange(steps + 1) / steps
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    path = q0 + (q1 - q0) * s[:, None]  # [steps+1, 7]
    grip = (tau >= 0.6).astype(np.float64)
    if flaws.reverse:
        grip = 1.0 - grip
    held = np.zeros(len(path), dtype=bool)  # frames where the operator holds the last command
    pause = int(round(flaws.pause_s * fps))
    if pause:
        at = int(0.4 * steps)
        path = np.concatenate([path[:at], np.repeat(path[at : at + 1], pause, 0), path[at:]])
        grip = np.concatenate([grip[:at], np.repeat(grip[at : at + 1], pause), grip[at:]])
        held = np.concatenate([held[:at], np.ones(pause, bool), held[at:]])
    start, end = int(round(flaws.idle_start_s * fps)), int(round(flaws.idle_end_s * fps))
    path = np.concatenate([np.repeat(path[:1], start, 0), path, np.repeat(path[-1:], end, 0)])
    grip = np.concatenate([np.repeat(grip[:1], start), grip, np.repeat(grip[-1:], end)])
    held = np.concatenate([np.ones(start, bool), held, np.ones(end, bool)])
    target = path[1:].copy()
    if flaws.jitter:
        # A held command is held exactly (as a teleop "hold" does); only moving targets shake.
        target += rng.normal(0.0, flaws.jitter, target.shape) * ~held[1:, None]
    # The robot tracks its target with one frame of lag: the state is the previous target.
    q = np.concatenate([path[:1], target[:-1]])
    t = len(target)
    data = {
        "action": np.concatenate([target, grip[1:, None]], axis=1).astype(np.float32),
        "obs.joint_pos": q.astype(np.float32),
        "obs.joint_vel": (np.diff(np.concatenate([q[:1], q]), axis=0) * fps).astype(np.float32),
        "obs.gripper": grip[:-1, None].astype(np.float32),
        "obs.goal": np.repeat(goal[None].astype(np.float32), t, 0),
    }
    if extra_obs:
        data["obs.object"] = np.repeat(rng.normal(0.0, 1.0, (1, extra_obs)).astype(np.float32), t, 0)
    return data


PROFILES = {
    # name: (jitter rad, idle start s, pause s, speed range); mirrors a mixed multi-operator dataset
    "expert": (0.0, (0.0, 0.0), (0.0, 0.0), (1.0, 1.0)),
    "good": (0.002, (0.0, 0.3), (0.0, 0.0), (0.9, 1.1)),
    "okay": (0.006, (0.3, 1.0), (0.0, 0.4), (0.8, 1.2)),
    "poor": (0.04, (1.0, 3.0), (0.8, 2.0), (0.6, 1.4)),
}


def mixed_episodes(n: int, seed: int = 0, *, fps: float = 20.0, duration_s: float = 3.0, extra_obs: int = 0):
    """``n`` (data, info) pairs cycling through :data:`PROFILES`; a fifth of "poor" ones head the
    wrong way (``mirror``)."""
    rng = np.random.default_rng(seed)
    names = list(PROFILES)
    out = []
    for i in range(n):
        name = names[i % len(names)]
        jitter, idle, pause, speed = PROFILES[name]
        flaws = Flaws(
            idle_start_s=float(rng.uniform(*idle)),
            pause_s=float(rng.uniform(*pause)),
            jitter=jitter,
            speed=float(rng.uniform(*speed)),
            mirror=name == "poor" and rng.random() < 0.2,
        )
        data = episode(rng, flaws, fps=fps, duration_s=duration_s, extra_obs=extra_obs)
        info = {"success": True, "seed": i, "source": "synthetic", "operator": name, "contradicting": flaws.mirror}
        out.append((data, info))
    return out


def write_store(path: str | Path, episodes, *, fps: float = 20.0, extra_obs: int = 0, overwrite: bool = True) -> Path:
    """Create a store at ``path`` holding ``episodes`` ((data, info) pairs); returns the path."""
    with EpisodeStore.create(path, meta(fps, extra_obs), overwrite=overwrite) as store:
        for first in range(0, len(episodes), 500):
            store.append_episodes(episodes[first : first + 500])
    return Path(path)
