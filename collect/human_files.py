"""Synthetic human input files made from scripted demonstrations (for tests, demos and benchmarks).

    python -m demo.collect.human_files --task pick --episodes 20 --seed 0 --out-dir human/

writes, from the scripted expert's episodes ``episode_seed(seed, i)`` (the same initial states as
``demo collect --source scripted --seed S``):

- ``POSES.jsonl``: the measured end-effector path re-expressed as a hand tracked in another frame
  (:class:`TrackerFrame`: rotated, offset, motion scaled by 1.3, a few mm of position noise, a
  little rotation noise and timestamp jitter, at 60 Hz), with the gripper command as the grip
  value and a header ``{"episode_seed": N}`` per episode;
- ``CALIB.json``: the exact tracker -> base calibration of that frame (for ``--calib``);
- ``JOINTS.csv``: the measured joint trajectory at 100 Hz with encoder noise, plus the gripper
  command, one ``episode_seed`` per episode;
- ``LEADER.csv``: a leader arm moved along the same joint path by a person of a given skill
  (:data:`LEADER_PROFILES`: a reaction latency, a physiological tremor of 8-12 Hz, and a hand that
  follows the intended path as a damped spring, overshooting where it is underdamped), in the leader's
  readings (the robot config's ``[leader]`` calibration inverted), at 200 Hz.

=======  ==========  ============  ================================
leader   latency     tremor        hand: damping ratio, frequency
=======  ==========  ============  ================================
good     0.05 s      0.001 rad     0.9, 6 Hz (no overshoot)
okay     0.15 s      0.004 rad     0.6, 4 Hz (~10% overshoot)
poor     0.30 s      0.012 rad     0.35, 3 Hz (~30% overshoot)
=======  ==========  ============  ================================

For a robot of several arms in a Gymnasium environment (gym-aloha's pair in :mod:`demo.sim.aloha_scene`)::

    python -m demo.collect.human_files --env demo.sim.aloha_scene:transfer_cube \
        --expert demo.collect.aloha:transfer_cube --robot aloha_vx300s.toml --episodes 10 --out-dir human/

writes ``LEADER.csv`` alone: each arm's leader moved along that environment's scripted expert's joint targets
by a person of the profile (one person per arm: their tremors differ), columns ``ARM.JOINT`` and
``ARM.gripper`` (:mod:`demo.collect.leader_arms`).

Retarget them with ``collect_vr(task, POSES.jsonl, out, scale=1/1.3)`` (first pose aligned to the
EE) or ``collect_vr(..., calib=CALIB.json)`` (absolute), ``collect_kinesthetic(task,
JOINTS.csv, out)`` and ``collect_kinesthetic(task, LEADER.csv, out, leader=True)``.
"""

from __future__ import annotations

import argparse
import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demo.collect.foreign import foreign_episode
from demo.collect.leader import calibration as leader_calibration
from demo.collect.leader_arms import LeaderArms
from demo.collect.scripted import CollectConfig, make_env_for, scripted_episode
from demo.seeds import episode_seed
from demo.sim import load_robot, make_env
from demo.sim.arms import closedness_from_gripper, load_arms
from demo.sim.foreign import task_name
from demo.sim.robot import LeaderCalibration
from demo.sim.geometry import axis_angle_quat, quat_conj, quat_mul


@dataclass(frozen=True)
class TrackerFrame:
    """Where the synthetic tracker is: ``p_tracker = offset + scale * R p_base`` (+ noise)."""

    rotation: tuple[float, ...] = tuple(  # base z-up -> tracker y-up (OpenXR style), turned 35 deg
        quat_mul(axis_angle_quat(np.array([0.0, 1.0, 0.0]), np.deg2rad(35.0)),
                 axis_angle_quat(np.array([1.0, 0.0, 0.0]), -np.pi / 2)).tolist()
    )
    offset: tuple[float, float, float] = (0.42, 1.05, -0.7)  # tracker units
    scale: float = 1.3  # tracker units per robot metre: the hand moves 1.3x the robot
    noise_m: float = 0.002  # std of position noise per axis, in robot metres (x scale in the file)
    rot_noise_rad: float = 0.004  # std of rotation noise per axis
    rate_hz: float = 60.0
    time_jitter_s: float = 0.002

    def calibration(self) -> dict[str, Any]:
        """The inverse map, as a ``--calib`` file: ``p_base = translation + s R^T p_tracker``."""
        r_inv = quat_conj(np.array(self.rotation))
        return {
            "rotation": r_inv.tolist(),
            "translation": (-_rotate(r_inv, np.array(self.offset)) / self.scale).tolist(),
            "scale": 1.0 / self.scale,
        }


@dataclass(frozen=True)
class JointFileParams:
    rate_hz: float = 100.0
    noise_rad: float = 2e-4  # encoder noise std


@dataclass(frozen=True)
class LeaderProfile:
    """How a person moving a leader arm departs from the path they intend (module docstring's table)."""

    name: str
    latency_s: float  # the leader starts following the intended path this late
    tremor_rad: float  # amplitude of the 8-12 Hz tremor on every joint
    damping: float  # damping ratio of the hand's second-order follow of the intended path (< 1: overshoot)
    frequency_hz: float  # its natural frequency
    rate_hz: float = 200.0  # the leader's encoders


LEADER_PROFILES = {p.name: p for p in (
    LeaderProfile("good", 0.05, 0.001, 0.9, 6.0),
    LeaderProfile("okay", 0.15, 0.004, 0.6, 4.0),
    LeaderProfile("poor", 0.30, 0.012, 0.35, 3.0),
)}


@dataclass
class ScriptedPath:
    seed: int  # env.reset seed
    fps: float
    joints: tuple[str, ...]
    ee_pos: np.ndarray  # (T, 3) base frame, measured
    ee_quat: np.ndarray  # (T, 4)
    joint_pos: np.ndarray  # (T, n_arm), measured
    gripper: np.ndarray  # (T,) command
    joint_command: np.ndarray | None = None  # (T, n_arm) the expert's joint targets (what a leader arm would hold)
    success: bool = True
    extra: dict[str, Any] = field(default_factory=dict)


def scripted_paths(task: str, episodes: int, seed: int, robot: str | None = None,
                   task_options: dict[str, Any] | None = None) -> list[ScriptedPath]:
    """Run the scripted expert (``demo collect --source scripted`` episodes) and keep its paths."""
    config = CollectConfig(task=task, episodes=episodes, seed=seed, robot=robot, task_options=dict(task_options or {}))
    env = make_env_for(config)
    out = []
    try:
        for i in range(episodes):
            data, info = scripted_episode(env, config, i)
            out.append(ScriptedPath(
                seed=int(info["seed"]), fps=float(env.fps), joints=tuple(env.robot.arm_joints),
                ee_pos=data["obs.ee_pos"].astype(np.float64), ee_quat=data["obs.ee_quat"].astype(np.float64),
                joint_pos=data["obs.joint_pos"].astype(np.float64), gripper=data["action"][:, -1].astype(np.float64),
                joint_command=data["action"][:, :-1].astype(np.float64),
                success=bool(info["success"]),
            ))
    finally:
        env.close()
    return out


def pose_lines(path: ScriptedPath, frame: TrackerFrame, rng: np.random.Generator, task: str) -> list[str]:
    """The JSONL lines of one episode: header, then hand poses in the tracker frame."""
    lines = [json.dumps({"episode_seed": path.seed, "task": task, "operator": "synthetic"})]
    duration = (len(path.ee_pos) - 1) / path.fps
    n = int(np.floor(duration * frame.rate_hz)) + 1
    t = np.arange(n) / frame.rate_hz
    t[1:-1] += rng.uniform(-frame.time_jitter_s, frame.time_jitter_s, n - 2)
    rot = np.array(frame.rotation)
    for tj in t:
        pos, quat, grip = _path_at(path, float(tj))
        pos_t = np.array(frame.offset) + frame.scale * (_rotate(rot, pos) + rng.normal(0.0, frame.noise_m, 3))
        noise = rng.normal(0.0, frame.rot_noise_rad, 3)
        quat_t = quat_mul(rot, quat_mul(axis_angle_quat(noise, float(np.linalg.norm(noise))), quat))
        lines.append(json.dumps({
            "t": round(float(tj), 6), "pos": [round(float(v), 6) for v in pos_t],
            "quat": [round(float(v), 7) for v in quat_t / np.linalg.norm(quat_t)], "grip": float(grip),
        }))
    return lines


def _path_at(path: ScriptedPath, t: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Measured EE pose at time ``t`` (linear / normalised-linear between frames), gripper command held."""
    x = t * path.fps
    i = int(min(np.floor(x), len(path.ee_pos) - 1))
    j = min(i + 1, len(path.ee_pos) - 1)
    w = min(max(x - i, 0.0), 1.0)
    pos = (1 - w) * path.ee_pos[i] + w * path.ee_pos[j]
    qi, qj = path.ee_quat[i], path.ee_quat[j]
    if qi @ qj < 0:
        qj = -qj
    quat = (1 - w) * qi + w * qj
    return pos, quat / np.linalg.norm(quat), float(path.gripper[i])


def joint_rows(path: ScriptedPath, params: JointFileParams, rng: np.random.Generator) -> list[list[Any]]:
    duration = (len(path.joint_pos) - 1) / path.fps
    n = int(np.floor(duration * params.rate_hz + 1e-9)) + 1
    t = np.arange(n) / params.rate_hz
    src = np.arange(len(path.joint_pos)) / path.fps
    q = np.stack([np.interp(t, src, path.joint_pos[:, j]) for j in range(path.joint_pos.shape[1])], axis=1)
    q += rng.normal(0.0, params.noise_rad, q.shape)
    grip = path.gripper[np.minimum(np.floor(t * path.fps + 1e-9).astype(int), len(path.gripper) - 1)]
    return [[path.seed, f"{tj:.4f}", *[f"{v:.6f}" for v in qj], f"{g:g}"] for tj, qj, g in zip(t, q, grip)]


def leader_rows(path: ScriptedPath, leader: LeaderCalibration, profile: LeaderProfile,
                rng: np.random.Generator) -> list[list[Any]]:
    """One episode of ``LEADER.csv``: the expert's joint targets as a person would move the leader along them (on
    ALOHA the leader's position is the follower's target: a perfect operator reproduces the expert's episode)."""
    dt = 1.0 / profile.rate_hz
    duration = (len(path.joint_pos) - 1) / path.fps + profile.latency_s + 0.3  # the hand settles at the end
    t = np.arange(int(np.floor(duration * profile.rate_hz)) + 1) * dt
    target = path.joint_command if path.joint_command is not None else path.joint_pos
    src = np.arange(len(target)) / path.fps
    late = np.clip(t - profile.latency_s, 0.0, src[-1])
    intended = np.stack([np.interp(late, src, target[:, j]) for j in range(target.shape[1])], axis=1)
    w, zeta = 2 * np.pi * profile.frequency_hz, profile.damping
    hand, speed = intended[0].copy(), np.zeros(intended.shape[1])
    moved = np.empty_like(intended)
    for k in range(len(t)):  # semi-implicit Euler of x'' = w^2 (q - x) - 2 zeta w x'
        speed += dt * (w * w * (intended[k] - hand) - 2 * zeta * w * speed)
        hand = hand + dt * speed
        moved[k] = hand
    freq, phase = rng.uniform(8.0, 12.0, intended.shape[1]), rng.uniform(0.0, 2 * np.pi, intended.shape[1])
    moved += profile.tremor_rad * np.sin(2 * np.pi * freq * t[:, None] + phase)
    readings = leader.readings(moved)
    grip = leader.gripper_reading(path.gripper[np.minimum(np.floor(late * path.fps + 1e-9).astype(int), len(path.gripper) - 1)])
    return [[path.seed, f"{tk:.4f}", *[f"{v:.6f}" for v in qk], f"{g:.6f}"] for tk, qk, g in zip(t, readings, grip)]


def leader_arms_rows(actions: np.ndarray, seed: int, fps: float, leaders: LeaderArms,
                     gripper_command: tuple[float, float], profile: LeaderProfile,
                     rng: np.random.Generator) -> list[list[Any]]:
    """One episode of a several-arm ``LEADER.csv`` from an environment's actions [T, A] (each arm's joint targets,
    rad, then its gripper command): each arm's leader moved along its own targets as :func:`leader_rows` moves one."""
    per_arm, start = [], 0
    for arm, cal in zip(leaders.arms.arms, leaders.calibrations):
        n = arm.n_arm
        q = actions[:, start:start + n]
        closedness = closedness_from_gripper(actions[:, start + n], gripper_command)
        path = ScriptedPath(seed, fps, arm.arm_joints, ee_pos=np.zeros((len(q), 3)), ee_quat=np.zeros((len(q), 4)),
                            joint_pos=q, gripper=closedness, joint_command=q)
        per_arm.append(leader_rows(path, cal, profile, rng))
        start += n + 1
    return [per_arm[0][k][:2] + [cell for rows in per_arm for cell in rows[k][2:]] for k in range(len(per_arm[0]))]


def write_leader_arms_file(
    path: str | Path,
    env_name: str,
    expert: str,
    robot: str,
    episodes: int = 10,
    seed: int = 0,
    *,
    profile: LeaderProfile = LEADER_PROFILES["good"],
    task_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """A several-arm ``LEADER.csv`` at ``path`` from ``expert``'s episodes ``episode_seed(seed, i)`` in the
    environment ``env_name`` (the module docstring); returns a summary."""
    leaders = LeaderArms(load_arms(robot))
    env = make_env(task_name(env_name), **(task_options or {}))
    rng = np.random.default_rng([seed, 9])
    rows: list[list[Any]] = []
    successes = 0
    try:
        gripper_command = leaders.arms.check_env(env, f"--env {env_name}")
        for i in range(episodes):
            s = episode_seed(seed, i)
            data, info = foreign_episode(env, expert, s)
            successes += int(info["success"])
            rows += leader_arms_rows(data["action"].astype(np.float64), s, env.fps, leaders, gripper_command, profile, rng)
    finally:
        env.close()
    header = ["episode_seed", "t"]
    for i in range(len(leaders.arms.arms)):
        header += [c for c in leaders.joint_columns if c.startswith(f"{leaders.arms.arm_names[i]}.")]
        header.append(leaders.gripper_columns[i])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
    return {"file": str(path), "env": env_name, "expert": expert, "episodes": episodes, "seed": seed,
            "scripted_successes": successes, "leader_profile": profile.name}


def write_human_files(
    out_dir: str | Path,
    task: str = "pick",
    episodes: int = 20,
    seed: int = 0,
    *,
    robot: str | None = None,
    task_options: dict[str, Any] | None = None,
    frame: TrackerFrame = TrackerFrame(),
    joints: JointFileParams = JointFileParams(),
    leader: LeaderProfile = LEADER_PROFILES["good"],
) -> dict[str, Any]:
    """Write POSES.jsonl, CALIB.json, JOINTS.csv and LEADER.csv into ``out_dir``; returns a summary."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = scripted_paths(task, episodes, seed, robot, task_options)
    rng = np.random.default_rng([seed, 8])
    lines: list[str] = []
    for p in paths:
        lines += pose_lines(p, frame, rng, task)
    (out / "POSES.jsonl").write_text("\n".join(lines) + "\n")
    (out / "CALIB.json").write_text(json.dumps(frame.calibration(), indent=2) + "\n")
    with open(out / "JOINTS.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["episode_seed", "t", *paths[0].joints, "gripper"])
        for p in paths:
            writer.writerows(joint_rows(p, joints, rng))
    calibration = leader_calibration(load_robot(robot))
    with open(out / "LEADER.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["episode_seed", "t", *calibration.joints, "gripper"])
        for p in paths:
            writer.writerows(leader_rows(p, calibration, leader, rng))
    return {
        "out_dir": str(out), "task": task, "episodes": episodes, "seed": seed,
        "scripted_successes": sum(p.success for p in paths),
        "files": ["POSES.jsonl", "CALIB.json", "JOINTS.csv", "LEADER.csv"], "leader_profile": leader.name,
        "vr_scale": 1.0 / frame.scale,
    }


def _rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    w, x, y, z = quat
    u = np.array([x, y, z])
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m demo.collect.human_files", description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="pick")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out-dir", required=True)
    parser.add_argument("--robot", default=None, help="robot config TOML (default: built-in)")
    parser.add_argument("--leader-profile", default="good", choices=sorted(LEADER_PROFILES),
                        help="the person moving the leader arm (LEADER.csv)")
    parser.add_argument("--env", default=None, help="a Gymnasium environment of a robot of several arms: LEADER.csv "
                                                    "alone, from --expert's episodes (--robot: its ARMS.toml)")
    parser.add_argument("--expert", default=None, help="--env: its scripted expert, module:callable")
    args = parser.parse_args(argv)
    if args.env is not None:
        if args.expert is None or args.robot is None:
            parser.error("--env needs --expert and --robot (the robot of several arms)")
        summary = write_leader_arms_file(Path(args.out_dir) / "LEADER.csv", args.env, args.expert, args.robot,
                                         args.episodes, args.seed, profile=LEADER_PROFILES[args.leader_profile])
        print(json.dumps(summary, indent=2))
        return 0
    summary = write_human_files(args.out_dir, args.task, args.episodes, args.seed, robot=args.robot,
                                leader=LEADER_PROFILES[args.leader_profile])
    d = summary["out_dir"]
    print(json.dumps(summary, indent=2))
    print(f"# replay:\n#   collect_vr('{args.task}', '{d}/POSES.jsonl', OUT, scale={summary['vr_scale']:.6f})"
          f"\n#   collect_vr('{args.task}', '{d}/POSES.jsonl', OUT, calib='{d}/CALIB.json')"
          f"\n#   collect_kinesthetic('{args.task}', '{d}/JOINTS.csv', OUT)"
          f"\n#   collect_kinesthetic('{args.task}', '{d}/LEADER.csv', OUT, leader=True)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
