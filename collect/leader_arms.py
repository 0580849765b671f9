"""`demo collect --env ENV --source leader --robot ARMS.toml --input LEADER.csv`: leader-follower capture
(ALOHA, Zhao et al. 2023) for a robot of several arms (:mod:`demo.sim.arms`) in a Gymnasium environment
whose action is those arms' joint targets, such as gym-aloha's scene (:mod:`demo.sim.aloha_scene`).

Input: the one-arm leader file (:mod:`demo.collect.leader`) with one set of columns per arm, each named
``ARM.COLUMN`` after the robot's ``[[arms]]`` names::

    episode_seed,t,left.waist,...,left.wrist_rotate,left.gripper,right.waist,...,right.gripper
    1234,0.000,0.0,-0.96,...,0.31,0.0,...

at any rate. Each arm's ``[leader]`` table (in its config) names its joint columns (default: the arm's joints
without its prefix) and calibrates them, ``follower = sign * reading + offset``, and its gripper's reading from
its open to its closed value onto closedness 0 .. 1 (:class:`demo.sim.robot.LeaderCalibration`).

The environment must name its action's dimensions as the robot names them (``left.waist`` ... ``right.gripper``,
:attr:`demo.sim.arms.ArmsConfig.action_names`; checked) and say what its gripper command is at open and at closed
(``gripper_command``: gym-aloha's normalised finger opening is ``(1, 0)``). Joint targets are in rad.

Playback, as on ALOHA: the calibrated recording is resampled to the environment's control rate (joints linear,
grippers the latest reading); from ``env.reset(episode_seed)`` the follower's servos are commanded, at control
step ``k``, the leaders' position at ``k``, which is also the recorded action. The followers start where the
environment puts them (record the leaders from that pose). Readings outside a joint's range are clipped and
flagged (``info.ik_ok``, ``info.ik_error``), as for one arm. Where the observation holds ``obs.agent_pos`` laid
out as the action (gym-aloha's), the **tracking error**, leader at step ``k`` against follower at ``k + 1``, is
reported per arm joint (rad).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from demo.collect.human import HumanCollectResult, HumanConfig, TAIL_S, episode_info, record_episodes, reset_seed
from demo.collect.kinesthetic import LIMIT_TOL, JointTrack, joint_ranges, parse_joint_csv, resample_joints
from demo.collect.leader import calibration, tracking_summary
from demo.errors import DemoError
from demo.progress import Progress
from demo.sim.arms import MEASURED_KEY, ArmsConfig, gripper_from_closedness, load_arms
from demo.sim.foreign import ENV_PREFIX
from demo.sim.robot import LeaderCalibration
from demo.sim.rollout import StepCommand, rollout


class LeaderArms:
    """The leaders of a robot of several arms: each arm's calibration, file columns and joint limits."""

    def __init__(self, arms: ArmsConfig):
        self.arms = arms
        self.calibrations: list[LeaderCalibration] = [calibration(arm) for arm in arms.arms]
        self.joint_columns = tuple(f"{name}.{column.removeprefix(arm.arm_prefix)}"
                                   for name, arm, cal in zip(arms.arm_names, arms.arms, self.calibrations)
                                   for column in cal.joints)
        self.gripper_columns = tuple(f"{name}.gripper" for name in arms.arm_names)
        self.joint_names = tuple(n for n in arms.action_names if not n.endswith(".gripper"))  # follower joints
        limits = []
        for arm in arms.arms:
            ranges = joint_ranges(arm)
            limits += [ranges.get(j, (-np.inf, np.inf)) for j in arm.arm_joints]
        self.limits = np.array(limits)  # (n joints, 2): rad, unlimited joints +-inf

    def parse(self, path: str | Path) -> list[JointTrack]:
        """The file's episodes, in the leaders' own readings (one-line errors naming ``path:line``)."""
        return parse_joint_csv(path, self.joint_columns, gripper_in_unit_range=False, grippers=self.gripper_columns)

    def actions(self, track: JointTrack, fps: float, gripper_command: tuple[float, float]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One episode as the environment's actions at ``fps``: (actions [K, A] in the action's order, ik_ok [K, 1],
        ik_error [K, 2]: (0, rad beyond a joint's range))."""
        readings, grips = resample_joints(track, fps)
        grips = grips.reshape(len(grips), -1)
        parts, start = [], 0
        for i, (arm, cal) in enumerate(zip(self.arms.arms, self.calibrations)):
            n = arm.n_arm
            parts += [cal.follower(readings[:, start:start + n]),
                      gripper_from_closedness(cal.closedness(grips[:, i]), gripper_command)[:, None]]
            start += n
        actions = np.concatenate(parts, axis=1)
        joints = self.arms.joint_dims()
        clipped = np.clip(actions[:, joints], self.limits[:, 0], self.limits[:, 1])
        excess = np.abs(actions[:, joints] - clipped).max(axis=1)
        actions[:, joints] = clipped
        error = np.stack([np.zeros_like(excess), excess], axis=1)
        return actions.astype(np.float32), (excess <= LIMIT_TOL)[:, None], error.astype(np.float32)

    def tracking_lag(self, commanded: np.ndarray, data: dict[str, np.ndarray]) -> np.ndarray | None:
        """Mean |leader at k - follower at k + 1| per follower joint (rad), or None without the arms' measured
        joints (:data:`demo.sim.arms.MEASURED_KEY`)."""
        measured = data.get(MEASURED_KEY)
        if measured is None or measured.shape[-1] != commanded.shape[-1]:
            return None
        joints = self.arms.joint_dims()
        steps = min(len(commanded), len(measured)) - 1
        if steps < 1:
            return np.zeros(len(joints))
        return np.abs(commanded[:steps, joints] - measured[1:steps + 1, joints]).mean(axis=0)


def leader_arms_episode(env: Any, actions: np.ndarray, seed: int) -> Any:
    """Play one episode's leader actions from ``env.reset(seed)``: step ``k`` commands ``actions[k]`` (held for at
    most ``TAIL_S`` past the recording) and records it as the action."""
    env.reset(seed)
    last = len(actions) - 1

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        a = actions[min(t, last)]
        return StepCommand(executed=a, label=a)

    horizon = getattr(env, "horizon", None)
    steps = len(actions) + int(round(TAIL_S * env.fps))
    return rollout(env, seed, act, reset=False, max_steps=min(steps, horizon) if horizon else steps)


def collect_leader_arms(
    env_name: str,
    input_csv: str | Path,
    out: str | Path,
    seed: int = 0,
    *,
    robot: str | None,
    operator: str | None = None,
    task_options: dict[str, Any] | None = None,
    instruction: str = "",
    append: bool = False,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> HumanCollectResult:
    """Play every episode of a several-arm leader file through the environment ``env_name`` into the store at ``out``;
    the result's ``tracking_error_rad`` holds each follower joint's mean and max tracking error over the episodes."""
    if robot is None:
        raise DemoError("--robot", "--source leader in an environment needs its robot of several arms (ARMS.toml)")
    leaders = LeaderArms(load_arms(robot))
    tracks = leaders.parse(input_csv)  # the whole file before the store opens: a bad line changes nothing
    config = HumanConfig(
        task=env_name, source="leader", input=str(input_csv), seed=seed, operator=operator, robot=robot,
        task_options=dict(task_options or {}), instruction=instruction,
        settings={"leader": {name: cal.to_json() for name, cal in zip(leaders.arms.arm_names, leaders.calibrations)}},
    )
    lags: list[np.ndarray] = []
    command: dict[str, tuple[float, float]] = {}

    def run(env: Any, index: int, count: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if not command:
            command["gripper"] = leaders.arms.check_env(env, f"--env {env_name.removeprefix(ENV_PREFIX)}")
        track = tracks[index]
        s = reset_seed(track.episode, seed, index)
        actions, ik_ok, ik_err = leaders.actions(track, env.fps, command["gripper"])
        episode = leader_arms_episode(env, actions, s)
        data = dict(episode.data)
        n = len(data["action"])
        held = np.minimum(np.arange(n), len(actions) - 1)  # past the recording: its last command, held
        data["info.ik_ok"], data["info.ik_error"] = ik_ok[held], ik_err[held]
        extra = {}
        lag = leaders.tracking_lag(actions[held], data)
        if lag is not None:
            lags.append(lag)
            extra["tracking_error_rad"] = float(lag.max())  # the episode's worst joint
        info = episode_info(config, track.episode, s, episode.success, episode.first_success_step, data["info.ik_ok"])
        return data, {**info, **extra}

    result = record_episodes(config, len(tracks), run, out, append=append, overwrite=overwrite, progress=progress)
    if lags:
        result.tracking_error_rad = tracking_summary(lags, leaders.joint_names)
    return result
