"""The robot behind a store: its config, kinematics, and the task scene its ``sim.state`` belongs to.

A store names its robot in ``meta.robot`` (the built-in arm, or a robot recorded by content whose
files the store carries; see :mod:`demo.sim.robot_record`) and its task in
``meta.task = {"name": ..., "options": {...}}``. Kinematics run on the robot MJCF alone (what FK
and IK need); the task scene is only built to read the measured arm joints out of recorded
``sim.state`` vectors, whose layout depends on the scene's objects.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.convert.kinematics import Kinematics
from demo.errors import DemoError
from demo.sim import make_env
from demo.sim.robot_record import resolve_robot
from demo.store import ActionSpec, StoreMeta

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclass
class RobotContext:
    """Everything convert needs to know about a store's robot."""

    robot: Any  # demo.sim.RobotConfig
    kin: Kinematics
    scene: mujoco.MjModel | None  # the task scene that recorded sim.state (None: task unknown here)
    scene_qpos_adr: np.ndarray | None  # arm joints' qpos addresses in the scene
    action_spec: ActionSpec | None  # the environment's joint_pos ActionSpec (None without a scene)

    @property
    def record(self) -> dict[str, Any]:
        """A small JSON record for provenance."""
        r = self.robot
        return {"name": r.name, "config": str(r.config_path) if r.config_path else None, "mjcf": str(r.mjcf_path),
                "ee_site": r.ee_site, "base_body": r.base_body, "arm_joints": list(r.arm_joints)}

    def home_q(self) -> np.ndarray:
        return np.array([self.robot.home_qpos[j] for j in self.robot.arm_joints])

    def arm_q_from_states(self, states: np.ndarray, where: object) -> np.ndarray:
        """Measured arm joint positions [E, n] from ``sim.state`` rows [E, nstate]."""
        if self.scene is None or self.scene_qpos_adr is None:
            raise DemoError(where, "cannot read sim.state: the store's task scene is not available")
        states = np.atleast_2d(np.asarray(states, dtype=np.float64))
        expected = mujoco.mj_stateSize(self.scene, _STATE)
        if states.shape[1] != expected:
            raise DemoError(where, f"sim.state has {states.shape[1]} values but the task scene's state has {expected}; "
                                   "was it recorded with another robot or task options?")
        data = mujoco.MjData(self.scene)
        out = np.empty((len(states), len(self.scene_qpos_adr)))
        for i, s in enumerate(states):
            mujoco.mj_setState(self.scene, data, s, _STATE)
            out[i] = data.qpos[self.scene_qpos_adr]
        return out


def load_context(meta: StoreMeta, where: str | Path, robot_override: str | Path | None = None,
                 purpose: str = "this conversion") -> RobotContext:
    """Load the robot a store names (or ``robot_override``), failing clearly when there is none.

    ``where``: the store directory (its ``robot/`` folder holds a recorded robot's files).
    """
    record = meta.robot or {}
    if robot_override is None and not record.get("config") and not record.get("files"):
        raise DemoError(where, f"names no robot (metadata 'robot.config' is empty), and {purpose} needs the "
                               "robot's kinematics; pass --robot ROBOT.toml")
    robot = resolve_robot(record, robot_override, where)
    try:
        model = robot.spec().compile()
    except DemoError:
        raise
    except Exception as exc:
        raise DemoError(robot.config_path, f"robot MJCF does not compile: {exc}") from None
    kin = Kinematics(model, robot.arm_joints, robot.ee_site, robot.base_body, where=robot.config_path)
    scene, adr, spec = _scene(meta, robot)
    return RobotContext(robot, kin, scene, adr, spec)


def _scene(meta: StoreMeta, robot: Any) -> tuple[mujoco.MjModel | None, np.ndarray | None, ActionSpec | None]:
    task = meta.task or {}
    name = task.get("name")
    if not name:
        return None, None, None
    try:
        env = make_env(name, robot=robot, **dict(task.get("options") or {}))
    except DemoError:
        return None, None, None  # a task this demo does not know (e.g. an imported dataset)
    try:
        adr = np.array([env.model.jnt_qposadr[env.model.joint(j).id] for j in robot.arm_joints], dtype=np.int64)
        return env.model, adr, env.action_spec
    finally:
        env.close()
