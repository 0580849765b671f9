"""`demo collect --source kinesthetic`: a recorded joint trajectory played through the simulator.

Input, ``JOINTS.csv`` (a person guiding an arm, recorded at any rate)::

    episode_seed,t,joint1,joint2,joint3,joint4,joint5,joint6,joint7,gripper
    1234,0.00,0.012,-0.781,...,0.0
    1234,0.01,0.013,-0.779,...,0.0

- A header row names the columns, in any order: ``t`` (s, strictly increasing within an
  episode), one column per arm joint of the robot config, by name (rad, measured joint
  positions), ``gripper`` (the gripper command, 0 = open .. 1 = closed) and, optionally,
  ``episode_seed``: the ``env.reset`` seed of the episode's initial state; a new value starts a
  new episode. Without it the file is one episode from ``episode_seed(seed, 0)``.
- Lines starting with ``#`` are comments.

Playback: the trajectory is resampled to the control rate (linear interpolation). The arm starts at
the recording's first configuration (the objects come from the seed: a person starts guiding
from wherever the arm was), and the command of frame ``k`` is the recorded configuration one
control step later, so the position servos reproduce the recorded motion rather than lag it by
a step. Joint values outside the robot's joint range are clipped for execution and flagged in
``info.ik_ok`` (never silently): the recording does not fit this robot there. A value more than the
range's own width beyond it (1e308, say) is no reading of that joint: the file is refused, naming
the line and the column. ``info.ee_target`` is the EE pose of the commanded configuration (MuJoCo
forward kinematics).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Mapping
from typing import Any

import numpy as np

from demo.collect.human import (
    HumanCollectResult,
    HumanCommand,
    HumanConfig,
    InputEpisode,
    check_time,
    episode_info,
    record_episodes,
    play_recording,
    reset_seed,
)
from demo.collect.retarget import ArmFK
from demo.errors import DemoError
from demo.progress import Progress
from demo.sim import RobotConfig, load_robot
from demo.sim.robot_model import joint_limits

LIMIT_TOL = 1e-3  # rad beyond a joint limit that still counts as inside (encoder noise)
FAR_BEYOND = 1.0  # a value this many range widths beyond a joint's range is refused, not clipped


@dataclass
class JointTrack:
    """One episode of a recorded joint trajectory."""

    episode: InputEpisode
    t: np.ndarray  # (N,) s
    q: np.ndarray  # (N, n_arm) rad, robot.arm_joints order
    gripper: np.ndarray  # (N,) 0 open .. 1 closed; (N, k) for a file of k grippers (a robot of several arms)


def joint_ranges(robot: RobotConfig) -> dict[str, tuple[float, float]]:
    """``(low, high)`` of each limited arm joint (rad, or m for a slide), from the robot's model."""
    model = robot.spec().compile()
    ids = {name: model.joint(name).id for name in robot.arm_joints}
    return {name: (float(model.jnt_range[j, 0]), float(model.jnt_range[j, 1]))
            for name, j in ids.items() if model.jnt_limited[j]}


def parse_joint_csv(path: str | Path, arm_joints: tuple[str, ...],
                    ranges: Mapping[str, tuple[float, float]] | None = None,
                    gripper_in_unit_range: bool = True, grippers: tuple[str, ...] = ("gripper",)) -> list[JointTrack]:
    """Read and validate a joint CSV; any problem is a DemoError naming ``path:line``. ``ranges``
    (:func:`joint_ranges`): a joint value far outside its joint's range is one. ``gripper_in_unit_range``:
    the gripper column is a command in [0, 1] (False: any finite reading, a leader's, calibrated later).
    ``grippers``: the gripper columns (several: a robot of several arms, each track's ``gripper`` [N, k])."""
    path = Path(path)
    if not path.is_file():
        raise DemoError(path, "joint file not found")
    try:
        text = path.read_text(encoding="utf-8-sig")  # tolerate a BOM (spreadsheet exports)
    except UnicodeDecodeError as exc:
        raise DemoError(path, f"not a UTF-8 text file ({exc.reason})") from None
    reader = csv.reader(text.splitlines())
    columns: dict[str, int] | None = None
    tracks: list[JointTrack] = []
    rows: list[tuple[float, np.ndarray, float]] = []
    current: tuple[int, int | None] | None = None  # (line, seed) of the open episode

    def close() -> None:
        if current is not None and rows:
            t, q, g = zip(*rows)
            tracks.append(JointTrack(InputEpisode(current[0], current[1], None), np.array(t), np.array(q), np.array(g)))

    for row in reader:
        number = reader.line_num
        where = f"{path}:{number}"
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        cells = [c.strip() for c in row]
        if columns is None:
            columns = _header(where, cells, arm_joints, grippers)
            continue
        if len(cells) != len(columns):
            raise DemoError(where, f"expected {len(columns)} values (as the header), got {len(cells)}")
        seed: int | None = None
        if "episode_seed" in columns:
            raw = cells[columns["episode_seed"]]
            try:
                seed = int(raw)
            except ValueError:
                raise DemoError(where, f"'episode_seed' must be an integer, got {raw!r}") from None
            if not 0 <= seed < 2**63:
                raise DemoError(where, f"'episode_seed' must be a non-negative 64-bit integer, got {seed}")
        if current is None or ("episode_seed" in columns and seed != current[1]):
            close()
            current, rows = (number, seed), []
        t = _number(where, "t", cells[columns["t"]])
        check_time(where, t, rows[-1][0] if rows else None, rows[0][0] if rows else None)
        q = np.array([_joint(where, j, cells[columns[j]], (ranges or {}).get(j)) for j in arm_joints])
        g = np.array([_number(where, name, cells[columns[name]]) for name in grippers])
        if gripper_in_unit_range and not ((0.0 <= g) & (g <= 1.0)).all():
            raise DemoError(where, f"'gripper' must be within 0 (open) .. 1 (closed), got {g[0]:g}")
        rows.append((t, q, g[0] if len(grippers) == 1 else g))
    if columns is None:
        raise DemoError(path, f"empty file: expected a header row (t, joint names, {', '.join(grippers)})")
    close()
    if not tracks:
        raise DemoError(path, "no samples after the header row")
    return tracks


def _header(where: str, cells: list[str], arm_joints: tuple[str, ...], grippers: tuple[str, ...]) -> dict[str, int]:
    columns = {name: i for i, name in enumerate(cells)}
    if len(columns) != len(cells):
        raise DemoError(where, "header names a column twice")
    need = ["t", *arm_joints, *grippers]
    missing = [c for c in need if c not in columns]
    if missing:
        raise DemoError(where, f"header lacks column(s) {', '.join(missing)} (needs t, {', '.join(arm_joints)}, "
                               f"{', '.join(grippers)}; optional episode_seed)")
    unknown = sorted(set(columns) - set(need) - {"episode_seed"})
    if unknown:
        raise DemoError(where, f"unknown column(s) {', '.join(unknown)}")
    return columns


def _number(where: str, name: str, raw: str) -> float:
    try:
        v = float(raw)
    except ValueError:
        raise DemoError(where, f"'{name}' is not a number: {raw!r}") from None
    if not math.isfinite(v):
        raise DemoError(where, f"'{name}' is not finite ({raw})")
    return v


def _joint(where: str, name: str, raw: str, limits: tuple[float, float] | None) -> float:
    """A joint value: a little outside its range is the robot's to clip and flag (a recording from
    a slightly different arm); more than ``FAR_BEYOND`` widths beyond it is no reading of the joint."""
    v = _number(where, name, raw)
    if limits is not None:
        lo, hi = limits
        margin = FAR_BEYOND * (hi - lo)
        if not lo - margin <= v <= hi + margin:
            raise DemoError(where, f"'{name}' = {v:g} is far outside the joint's range [{lo:g}, {hi:g}]: no reading "
                                   "of this joint (values near the range are clipped and flagged)")
    return v


def resample_joints(track: JointTrack, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(q [K, n], gripper [K]) at ``t0 + k / fps``: linear for joints, latest sample for the gripper."""
    t = track.t - track.t[0]
    k = int(math.floor(t[-1] * fps + 1e-9)) + 1
    tk = np.arange(k) / fps
    q = np.stack([np.interp(tk, t, track.q[:, j]) for j in range(track.q.shape[1])], axis=1)
    i = np.clip(np.searchsorted(t, tk + 1e-9, side="right") - 1, 0, len(t) - 1)
    return q, track.gripper[i]


def kinesthetic_episode(env: Any, track: JointTrack, seed: int, fk: ArmFK | None = None
                        ) -> tuple[Any, np.ndarray, np.ndarray]:
    """Play one joint track from ``env.reset(seed)``: (Episode, ik_ok [T,1], ik_error [T,2])."""
    return play_joint_track(env, track, seed, lookahead=1, fk=fk)[:3]


def play_joint_track(env: Any, track: JointTrack, seed: int, lookahead: int, fk: ArmFK | None = None
                     ) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray]:
    """Play one joint track, resampled to the control rate, from ``env.reset(seed)`` with the arm at its first
    configuration: control step ``t`` commands the recorded configuration of step ``t + lookahead`` (kinesthetic:
    1, so the servos reproduce the motion; a leader arm: 0, the follower's target is where the leader is now),
    clipped to the joint limits (an unlimited joint is not clipped) and flagged where clipping changed it.
    Returns (Episode, ik_ok [T, 1], ik_error [T, 2], the commanded arm configurations [T, n_arm])."""
    q, grip = resample_joints(track, env.fps)
    limits = joint_limits(env.model, [env.model.joint(j).id for j in env.robot.arm_joints])
    env.reset(seed)
    env.set_arm(q[0])
    fk = fk or ArmFK(env)
    last = len(q) - 1
    commanded: list[np.ndarray] = []

    def command_at(t: int) -> HumanCommand:
        target = q[min(t + lookahead, last)]
        clipped = np.clip(target, limits[:, 0], limits[:, 1])
        excess = float(np.max(np.abs(target - clipped)))
        commanded.append(clipped)
        pos, quat = fk(clipped)
        return HumanCommand(clipped, float(grip[min(t, last)]), np.r_[pos, quat], excess <= LIMIT_TOL, (0.0, excess))

    episode, ik_ok, ik_err = play_recording(env, seed, len(q), command_at)
    return episode, ik_ok, ik_err, np.asarray(commanded)


def collect_kinesthetic(
    task: str,
    input_csv: str | Path,
    out: str | Path,
    seed: int = 0,
    *,
    operator: str | None = None,
    robot: str | None = None,
    task_options: dict[str, Any] | None = None,
    cameras: tuple[tuple[str, int, int], ...] = (),
    instruction: str = "",
    append: bool = False,
    overwrite: bool = False,
    progress: Progress | None = None,
    leader: bool = False,
) -> HumanCollectResult:
    """Play every episode of a joint CSV through the simulator into the store at ``out``. ``leader``: the file is a
    leader arm's recording, followed as ALOHA does (:mod:`demo.collect.leader`); the result's ``tracking_error_rad``
    then holds each arm joint's mean and max tracking error over the episodes (rad)."""
    from demo.collect.leader import leader_episode, leader_tracks, tracking_summary  # it builds on this module

    robot_config = load_robot(robot)
    if leader:
        tracks, calibration = leader_tracks(input_csv, robot_config)
        source, settings = "leader", {"leader": calibration.to_json()}
    else:
        tracks = parse_joint_csv(input_csv, robot_config.arm_joints, joint_ranges(robot_config))
        source, settings = "kinesthetic", {"lookahead_steps": 1}
    config = HumanConfig(
        task=task, source=source, input=str(input_csv), seed=seed, operator=operator, robot=robot,
        task_options=dict(task_options or {}), cameras=tuple(cameras), settings=settings, instruction=instruction,
    )
    state: dict[str, ArmFK] = {}
    lags: list[np.ndarray] = []

    def run(env: Any, index: int, count: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        track = tracks[index]
        s = reset_seed(track.episode, seed, index)
        if "fk" not in state:
            state["fk"] = ArmFK(env)
        fk = state["fk"]
        extra = {}
        if leader:
            episode, ik_ok, ik_err, lag = leader_episode(env, track, s, fk)
            lags.append(lag)
            extra["tracking_error_rad"] = float(lag.max())  # the episode's worst joint
        else:
            episode, ik_ok, ik_err = kinesthetic_episode(env, track, s, fk)
        data = dict(episode.data)
        data["info.ik_ok"], data["info.ik_error"] = ik_ok, ik_err
        return data, {**episode_info(config, track.episode, s, episode.success, episode.first_success_step, ik_ok), **extra}

    result = record_episodes(config, len(tracks), run, out, append=append, overwrite=overwrite, progress=progress)
    if leader:
        result.tracking_error_rad = tracking_summary(lags, robot_config.arm_joints)
    return result
