"""`demo collect --source leader` (:func:`demo.collect.kinesthetic.collect_kinesthetic` with ``leader=True``):
leader-follower capture (ALOHA, Zhao et al. 2023) from a recorded leader arm.

A person moves a leader arm; the follower (the robot, here the simulated one) tracks the leader's joint
positions through its position servos at the control rate, and the leader's joint positions are the
recorded actions. Input, ``LEADER.csv`` (the leader's encoders, at any rate)::

    episode_seed,t,waist,shoulder,elbow,forearm_roll,wrist_angle,wrist_rotate,gripper
    1234,0.000,0.012,-0.961,...,0.18

the kinesthetic file's format (:mod:`demo.collect.kinesthetic`: a header row, ``t`` in s strictly
increasing within an episode, ``episode_seed`` optional, ``#`` comments) with the *leader's* columns:
one per arm joint, named by the robot config's ``[leader]`` table (default: the arm's joint names), and
``gripper``, the leader gripper's reading in its own units. The table calibrates them per joint,
``follower = sign * reading + offset``, and maps the gripper reading linearly from its open to its
closed value onto closedness 0 .. 1 (:class:`demo.sim.robot.LeaderCalibration`).

Playback: the calibrated trajectory is resampled to the control rate (linear; the gripper's latest
reading). The follower starts at the leader's first configuration (the objects come from the seed),
and at control step ``k`` its servos are commanded the leader's position at step ``k``, which is also
the recorded action: the follower lags the leader by its servos' response, as on ALOHA, and that lag
is the *tracking error*, measured per joint between the leader at step ``k`` and the follower one
control step later (rad; mean and max over the file, and each episode's worst joint mean in the
episode table's ``tracking_error_rad``). Readings outside the follower's joint range are clipped and
flagged in ``info.ik_ok``, as for kinesthetic files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from demo.collect.kinesthetic import JointTrack, parse_joint_csv, play_joint_track
from demo.collect.retarget import ArmFK
from demo.sim.robot import LeaderCalibration, RobotConfig


def calibration(robot: RobotConfig) -> LeaderCalibration:
    """The robot's ``[leader]`` table, or the identity (a leader of the same make, its joints as named here)."""
    n = robot.n_arm
    return robot.leader or LeaderCalibration(robot.arm_joints, (1.0,) * n, (0.0,) * n)


def follower_track(track: JointTrack, leader: LeaderCalibration) -> JointTrack:
    """A leader recording in this arm's units: joint positions (rad) and gripper closedness (0 .. 1)."""
    return JointTrack(track.episode, track.t, leader.follower(track.q), leader.closedness(track.gripper))


def leader_episode(env: Any, track: JointTrack, seed: int, fk: ArmFK | None = None
                   ) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray]:
    """Follow one calibrated leader track from ``env.reset(seed)``: (Episode, ik_ok [T, 1], ik_error [T, 2],
    tracking error [n_arm]: the mean |leader at k - follower at k + 1| per joint, rad)."""
    episode, ik_ok, ik_err, commanded = play_joint_track(env, track, seed, lookahead=0, fk=fk)
    measured = episode.data["obs.joint_pos"].astype(np.float64)  # the follower at each frame, before its command
    steps = min(len(commanded), len(measured)) - 1
    lag = np.abs(commanded[:steps] - measured[1:steps + 1]) if steps > 0 else np.zeros((1, commanded.shape[-1]))
    return episode, ik_ok, ik_err, lag.mean(axis=0)


def leader_tracks(path: str | Path, robot: RobotConfig) -> tuple[list[JointTrack], LeaderCalibration]:
    """A leader CSV's episodes, calibrated into ``robot``'s units, and the calibration."""
    leader = calibration(robot)
    return [follower_track(t, leader) for t in parse_joint_csv(path, leader.joints, gripper_in_unit_range=False)], leader


def tracking_summary(lags: list[np.ndarray], joints: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Per arm joint, the mean and max over episodes of each episode's mean tracking error (rad)."""
    per_joint = np.asarray(lags)
    return {joint: {"mean": float(per_joint[:, j].mean()), "max": float(per_joint[:, j].max())}
            for j, joint in enumerate(joints)}
