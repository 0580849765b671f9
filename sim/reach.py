"""`reach`: bring the end-effector to a random target pose (position and orientation).

Reset: target position uniform in x 0.35..0.62, |y| <= 0.25, z 0.08..0.40 m (base frame); target
orientation points the gripper down with a heading within +-0.8 rad of the home heading, tilted by
up to 0.35 rad about a random horizontal axis. The target is a mocap marker (part of the state).
Success: EE position within ``pos_tol`` (m) and orientation within ``rot_tol`` (rad) of the target.
Observations: ``obs.goal_pos`` [3] (m), ``obs.goal_quat`` [4] (wxyz, w >= 0), base frame.

Expert: straight to the target pose at its speed; style ``arc`` (m) lifts the path by up to that
height while the EE is far from the target (a curved approach instead of a straight one).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from demo.sim.geometry import axis_angle_quat, canonical_f32, down_quat, quat_angle, quat_mul
from demo.sim.scene import BaseFrame, add_marker_geom, add_mocap_body
from demo.sim.task import Expert, ExpertParams, Task
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env


@dataclasses.dataclass
class ReachParams(ExpertParams):
    arc: float = 0.0  # m of extra height while far from the target (0 = straight line)


class ReachExpert(Expert):
    Params = ReachParams
    VARIATIONS = {"arc": (0.0, 0.12)}
    p: ReachParams

    def act(self, env: "Env") -> np.ndarray:
        goal_pos, goal_quat = env.task.goal(env)  # type: ignore[attr-defined]
        ee = env.ee_pose()
        far = min(1.0, math.hypot(*(goal_pos[:2] - ee[0][:2])) / 0.15)
        target = goal_pos + np.array([0.0, 0.0, self.p.arc * far])
        return self.move(env, target, goal_quat, 0.0, ee=ee)


class Reach(Task):
    name = "reach"
    defaults = {"pos_tol": 0.01, "rot_tol": 0.1}
    expert_class = ReachExpert
    relative_goal_keys = ("obs.goal_pos-obs.ee_pos", "obs.goal_quat-obs.ee_quat")  # the rotation R_ee^T R_goal

    @property
    def horizon(self) -> int:
        return 100

    def build(self, spec: mujoco.MjSpec, base: BaseFrame) -> None:
        body = add_mocap_body(spec, "target")
        add_marker_geom(body, mujoco.mjtGeom.mjGEOM_SPHERE, [0.012], [0.1, 0.8, 0.2, 0.5])
        # A short rod along the target's approach axis (z) shows the orientation.
        add_marker_geom(body, mujoco.mjtGeom.mjGEOM_CAPSULE, [0.004], [0.1, 0.8, 0.2, 0.5], fromto=[0, 0, -0.06, 0, 0, 0])

    def bind(self, env: "Env") -> None:
        self.mocap = int(env.model.body_mocapid[env.model.body("target").id])

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        pos = np.array([rng.uniform(0.35, 0.62), rng.uniform(-0.25, 0.25), rng.uniform(0.08, 0.40)])
        yaw = env.home_yaw + rng.uniform(-0.8, 0.8)
        phi = rng.uniform(-math.pi, math.pi)
        tilt = axis_angle_quat(np.array([math.cos(phi), math.sin(phi), 0.0]), rng.uniform(0.0, 0.35))
        quat = quat_mul(tilt, down_quat(yaw))
        env.set_mocap_pose(self.mocap, pos, quat)

    def goal(self, env: "Env") -> tuple[np.ndarray, np.ndarray]:
        """Target pose in the base frame."""
        return env.mocap_pose(self.mocap)

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        return {
            "obs.goal_pos": FeatureSpec((3,), "float32", "target EE position, base frame", "m", ("x", "y", "z")),
            "obs.goal_quat": FeatureSpec((4,), "float32", "target EE orientation, base frame, w >= 0", "1", ("w", "x", "y", "z")),
        }

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        pos, quat = self.goal(env)
        out["obs.goal_pos"] = pos.astype(np.float32)
        out["obs.goal_quat"] = canonical_f32(quat)

    def success(self, env: "Env") -> bool:
        pos, quat = self.goal(env)
        ee_pos, ee_quat = env.ee_pose()
        return bool(
            np.linalg.norm(ee_pos - pos) < float(self.options["pos_tol"])
            and quat_angle(ee_quat, quat) < float(self.options["rot_tol"])
        )
