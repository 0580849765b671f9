"""placo as a second IK backend (``--ik placo``): the same differential IK as :mod:`demo.sim.ik`.

placo (Rhoban; pinocchio underneath) loads URDF, or MJCF through pinocchio's parser. The robot's
MJCF is handed over without keyframes (pinocchio rejects keyframes whose size differs from its
own model, e.g. once it adds a floating base); the floating base pinocchio adds is masked, as are
every joint but the arm's. One iteration solves, like mink's:

- FrameTask on the EE site (soft; weights = mink's costs squared, since mink weighs residuals by
  ``cost`` and placo objectives by ``weight``),
- JointsTask toward the home configuration (the posture task), a RegularizationTask (mink's
  Levenberg-Marquardt damping),
- joint and velocity limits (placo's own, with ``dt``),
- the table as a hard, linearised half-space: the EE site keeps ``collision_min_distance`` plus
  the fingers' reach past the site (:func:`finger_reach`, measured on the MuJoCo model) above the
  (horizontal) table top, closing at most ``collision_rate`` of the gap a step. mink's
  CollisionAvoidanceLimit does this with exact distances for every robot geom; this one is exact
  for a gripper pointing down, conservative when it is tilted.

placo and pinocchio work in the robot MJCF's world frame, which is the scene's world frame
(``demo.sim.scene`` builds the scene on the robot's MJCF).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import quat_to_mat
from demo.sim.ik import IKParams


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """Silence C++ prints on file descriptor 1 (placo announces every model it loads)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def load_placo_robot(robot: Any) -> Any:
    """A ``placo.RobotWrapper`` of a demo robot config (its MJCF, keyframes removed)."""
    import placo  # deferred: heavy dependency (placo)

    spec = robot.spec()
    for key in list(spec.keys):
        spec.delete(key)
    # The copy lives in a temporary folder: make mesh and texture folders absolute.
    folder = Path(robot.mjcf_path).resolve().parent
    spec.meshdir = str(folder / (spec.meshdir or ""))
    spec.texturedir = str(folder / (spec.texturedir or ""))
    try:
        xml = spec.to_xml()
    except Exception as exc:  # mujoco raises ValueError with the compiler's message
        raise DemoError(robot.config_path, f"cannot export the MJCF for placo: {exc}") from None
    fd, name = tempfile.mkstemp(prefix="demo_placo_", suffix=".xml")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(xml)
        flags = int(placo.Flags.mjcf) | int(placo.Flags.ignore_collisions)
        with quiet_stdout():
            wrapper = placo.RobotWrapper(name, flags)
    except (ValueError, RuntimeError) as exc:
        raise DemoError(robot.config_path or robot.mjcf_path, f"placo cannot load the robot: {exc}") from None
    finally:
        os.unlink(name)
    return wrapper


class PlacoIK:
    """Differential IK of the arm with placo: EE pose (world frame) -> arm joint targets.

    ``table``: ``(z_world, reach)``: keep the EE site ``reach + collision_min_distance`` above the
    table top at height ``z_world`` (``reach``: how far the fingers extend past the site).
    """

    def __init__(self, robot: Any, dt: float, params: IKParams = IKParams(), table: tuple[float, float] | None = None):
        import placo  # deferred: heavy dependency (placo)

        self.params = params
        self.joints = tuple(robot.arm_joints)
        self.robot = load_placo_robot(robot)
        r = self.robot
        names = list(r.joint_names())
        missing = [j for j in self.joints if j not in names]
        if missing:
            raise DemoError(robot.config_path, f"placo model lacks arm joint(s) {', '.join(missing)}")
        if robot.ee_site not in set(r.frame_names()):
            raise DemoError(robot.config_path, f"placo model has no frame for the EE site '{robot.ee_site}'")
        r.set_T_world_fbase(np.eye(4))
        for j, v in zip(self.joints, robot.max_joint_velocity):
            r.set_velocity_limit(j, float(v))
        r.update_kinematics()

        s = placo.KinematicsSolver(r)
        s.mask_fbase(True)
        for j in names:
            if j not in self.joints:
                s.mask_dof(j)
        s.dt = float(dt)
        s.enable_joint_limits(True)
        s.enable_velocity_limits(True)
        self.frame_task = s.add_frame_task(robot.ee_site, np.eye(4))
        self.frame_task.configure("ee", "soft", params.position_cost**2, params.orientation_cost**2)
        self.posture = s.add_joints_task()
        self.posture.set_joints({j: float(robot.home_qpos[j]) for j in self.joints})
        self.posture.configure("posture", "soft", params.posture_cost**2)
        s.add_regularization_task(float(params.damping))
        self.solver = s
        self.ee_frame = robot.ee_site
        self.dt = float(dt)
        self._table = None
        if table is not None:
            nq = r.model.nq
            constraint = s.add_joint_space_half_spaces_constraint(np.zeros((1, nq)), np.zeros(1))
            constraint.configure("table", "hard")  # placo constraints are soft by default
            self._table = (float(table[0]) + float(table[1]) + params.collision_min_distance, constraint)
        self._T = np.eye(4)
        self.failures = 0

    def set_q(self, q: np.ndarray) -> None:
        r = self.robot
        for j, v in zip(self.joints, q):
            r.set_joint(j, float(v))
        r.update_kinematics()

    def q(self) -> np.ndarray:
        return np.array([self.robot.get_joint(j) for j in self.joints])

    def step(self, q: np.ndarray, pos_world: np.ndarray, quat_world: np.ndarray) -> np.ndarray:
        """Arm joint targets one iteration (``dt``) from ``q`` toward the EE pose (world frame)."""
        self.set_q(q)
        T = self._T
        T[:3, :3] = quat_to_mat(quat_world)
        T[:3, 3] = pos_world
        self.frame_task.T_world_frame = T
        if self._table is not None:
            self._update_table()
        try:
            self.solver.solve(True)
        except RuntimeError:
            self.failures += 1
            return np.array(q, dtype=np.float64)
        return self.q()

    def _update_table(self) -> None:
        """One row ``A (q + dq) <= b`` keeping the EE site above the table.

        Linearised: ``z + J_z dq - z_min >= (1 - rate) (z - z_min)``: a step may close ``rate`` of
        the gap (and must open it again when the site is too low), as mink's collision limit.
        """
        z_min, constraint = self._table
        r = self.robot
        z = float(r.get_T_world_frame(self.ee_frame)[2, 3])
        jz = np.asarray(r.frame_jacobian(self.ee_frame, "world"))[2]  # (nv,), free flyer first (6)
        row = np.zeros(r.model.nq)
        row[7:] = -jz[6:]  # 1-dof joints: q column 7 + i <-> velocity column 6 + i
        q_now = np.asarray(r.state.q)
        constraint.A = row[None]
        constraint.b = np.array([row @ q_now + self.params.collision_rate * (z - z_min)])


def finger_reach(model: mujoco.MjModel, site: int) -> float:
    """How far (m) the geoms below the EE site's body extend past the site along its +z axis."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    body = int(model.site_bodyid[site])
    axis = data.site_xmat[site].reshape(3, 3)[:, 2]
    origin = data.site_xpos[site]
    reach = 0.0
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        while b > 0 and b != body:
            b = int(model.body_parentid[b])
        if b != body:
            continue
        rot = data.geom_xmat[g].reshape(3, 3)
        # Extent along the axis: centre plus the support of the geom's bounding box.
        half = model.geom_size[g] if int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_BOX) else \
            np.full(3, float(model.geom_rbound[g]))
        extent = float((data.geom_xpos[g] - origin) @ axis + np.abs(rot.T @ axis) @ half)
        reach = max(reach, extent)
    return reach


class PlacoBackend:
    """:class:`PlacoIK` behind the retargeter's backend interface."""

    name = "placo"

    def __init__(self, env: Any, dt: float, params: IKParams):
        m = env.model
        table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        plane = None
        if table >= 0:
            top = float(m.geom_pos[table][2] + m.geom_size[table][2])
            plane = (top, finger_reach(m, m.site(env.robot.ee_site).id))
        self.ik = PlacoIK(env.robot, dt, params, table=plane)

    def set_mocap(self, mocap_pos: np.ndarray, mocap_quat: np.ndarray) -> None:
        """Obstacles are not modelled in placo (only the table)."""

    def iterate(self, q: np.ndarray, pos_world: np.ndarray, quat_world: np.ndarray) -> np.ndarray:
        return self.ik.step(q, pos_world, quat_world)
