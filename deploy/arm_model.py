"""What the robot-side loop knows of the arm: its joint limits and its forward kinematics.

A robot's controller has its arm's model (a URDF, an MJCF) to check commands before they reach the
motors; here it is the task scene's own MuJoCo model, kept on the client's side. Positions are in the
scene frame (MuJoCo's world: the table top is the plane z = 0), m; joint values in rad (m for slides).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from demo.sim.robot_model import joint_limits

WORKSPACE_HEIGHT_M = 0.6  # the default workspace's top, above the table top


class ArmModel:
    """Joint limits and end-effector positions of the arm of ``task`` (built as ``make_env`` builds it)."""

    def __init__(self, task: str, options: dict[str, Any] | None = None):
        from demo.sim import make_env  # deferred: the client side imports the simulator only here

        env = make_env(task, **(options or {}))
        try:
            self.model = env.model
            joints = [env.model.joint(j).id for j in env.robot.arm_joints]
            self.limits = joint_limits(env.model, joints)  # [n_arm, 2], -inf..inf where unlimited
            self.qpos_adr = np.array([env.model.jnt_qposadr[j] for j in joints])
            self.ee_site = env.model.site(env.robot.ee_site).id
            table = env.model.geom("table")
        finally:
            env.close()
        self.data = mujoco.MjData(self.model)
        self.table = (np.asarray(table.pos, dtype=np.float64), np.asarray(table.size, dtype=np.float64))

    def ee_position(self, arm_q: np.ndarray) -> np.ndarray:
        """The EE site's position (m, scene frame) with the arm at ``arm_q`` (the rest of the scene at rest)."""
        self.data.qpos[self.qpos_adr] = arm_q
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.site_xpos[self.ee_site].copy()

    def table_workspace(self, height: float = WORKSPACE_HEIGHT_M) -> np.ndarray:
        """[2, 3]: the box over the table top, from its surface up to ``height`` (m): the end effector stays
        over the table and never below its surface."""
        centre, half = self.table
        top = centre[2] + half[2]
        return np.array([[centre[0] - half[0], centre[1] - half[1], top],
                         [centre[0] + half[0], centre[1] + half[1], top + height]])
