"""The scene every task builds on: a table, a floor, lights and cameras, and the robot attached.

Frames: every pose `demo.sim` reports or accepts is in the **scene frame**: the table top is the
plane z = 0, +x points away from the robot over the table. The robot's ``base_body`` sits at the
config's ``base_pos``/``base_quat`` in it (default: the origin, unrotated), so for a robot left at
its default place the scene frame *is* the robot's base frame. A robot whose workspace misses the
table moves with ``base_pos`` (closer: ``x > 0``; ``z`` is the base's height above the table top).

The robot MJCF is compiled on its own terms and attached (``MjSpec.attach``) to a scene spec of our
own: its ``<compiler>`` options (``angle``, ``autolimits``, ``inertiagrouprange``, ``meshdir``, ...)
and defaults apply to its elements only, and its keyframes are dropped (the env resets from the
config's home configuration by joint name), so nothing in the robot file changes a task object.
Its mesh and texture files are found relative to its own MJCF. Its ``<option>`` is replaced by the
scene's. Scene geoms use contact class contype=1 conaffinity=3, so they touch each other and the
robot (contype=2, conaffinity=1 on the built-in arm; robots with default contact bits touch them too).

Physics: timestep 2 ms, ``implicitfast``; the env steps ``n_substeps`` of them per control step.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from demo.sim.geometry import lookat_quat, quat_conj, quat_mul, quat_to_mat
from demo.sim.robot import RobotConfig

TIMESTEP = 0.002
TABLE_SIZE = (0.6, 0.7, 0.025)  # half extents (m) of the table top
TABLE_CENTER_X = 0.35  # table centre along base x (m)
SCENE_CONTYPE, SCENE_CONAFFINITY = 1, 3
CAMERA_NAMES = ("front", "side", "top", "wrist")

# Fixed cameras in the base frame: (eye, look-at point). "wrist" rides on the EE site's body.
_CAMERAS = {
    "front": ((1.25, 0.0, 0.6), (0.45, 0.0, 0.08)),
    "side": ((0.5, -1.05, 0.6), (0.5, 0.0, 0.1)),
    "top": ((0.5, 0.0, 1.4), (0.5, 0.0, 0.0)),
}


@dataclass(frozen=True)
class BaseFrame:
    """Pose of the robot base in the world (static)."""

    pos: np.ndarray
    quat: np.ndarray

    @property
    def rot(self) -> np.ndarray:
        return quat_to_mat(self.quat)

    def pos_to_world(self, p: Sequence[float]) -> list[float]:
        return (self.pos + self.rot @ np.asarray(p, dtype=np.float64)).tolist()

    def quat_to_world(self, q: Sequence[float]) -> list[float]:
        return quat_mul(self.quat, np.asarray(q, dtype=np.float64)).tolist()


SCENE_FRAME = BaseFrame(pos=np.zeros(3), quat=np.array([1.0, 0.0, 0.0, 0.0]))  # the scene frame is MuJoCo's world


def base_frame(robot: RobotConfig, spec: mujoco.MjSpec) -> BaseFrame:
    """Where the base body sits in the robot MJCF's own world at its default configuration."""
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    b = model.body(robot.base_body).id
    return BaseFrame(pos=data.xpos[b].copy(), quat=data.xquat[b].copy())


def robot_body_names(robot: RobotConfig, spec: mujoco.MjSpec) -> list[str]:
    """Bodies of the robot MJCF (before scene objects are added)."""
    return [b.name for b in spec.bodies if b.name and b.name != "world"]


def scene_spec(robot: RobotConfig, max_camera_size: tuple[int, int] = (0, 0)) -> tuple[mujoco.MjSpec, BaseFrame]:
    """Table, floor, lights, the named cameras and the robot; tasks add their objects to it.

    Returns the spec and the frame tasks work in (the scene frame, see the module docstring).
    """
    spec = mujoco.MjSpec()
    spec.compiler.degree = False  # our own elements are in radians; the robot keeps its own setting
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    attach_robot(spec, robot)

    base = SCENE_FRAME
    world = spec.worldbody
    spec.add_material(name="demo_table", rgba=[0.55, 0.45, 0.35, 1.0], specular=0.05, shininess=0.1)
    table_top = np.array([TABLE_CENTER_X, 0.0, -TABLE_SIZE[2]])
    world.add_geom(
        name="table",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=list(TABLE_SIZE),
        pos=base.pos_to_world(table_top),
        quat=base.quat.tolist(),
        material="demo_table",
        contype=SCENE_CONTYPE,
        conaffinity=SCENE_CONAFFINITY,
        friction=[0.6, 0.005, 0.0001],
    )
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[3.0, 3.0, 0.05],
        pos=base.pos_to_world([0.0, 0.0, -0.75]),
        rgba=[0.3, 0.33, 0.36, 1.0],
        contype=SCENE_CONTYPE,
        conaffinity=SCENE_CONAFFINITY,
    )
    if robot.base_pos[2] > 0.005:  # a base above the table top stands on a riser (visual only: no contacts)
        h = robot.base_pos[2] / 2
        world.add_geom(name="robot_riser", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.09, h, 0],
                       pos=[robot.base_pos[0], robot.base_pos[1], h], rgba=[0.35, 0.35, 0.38, 1.0],
                       contype=0, conaffinity=0, group=1)
    world.add_light(name="key", pos=base.pos_to_world([0.4, -0.4, 2.0]), dir=[0.0, 0.2, -1.0], castshadow=False, diffuse=[0.45] * 3, specular=[0.05] * 3)
    world.add_light(name="fill", pos=base.pos_to_world([1.5, 0.8, 1.5]), dir=[-0.6, -0.3, -0.7], castshadow=False, diffuse=[0.25] * 3, specular=[0.0] * 3)
    spec.visual.headlight.diffuse = [0.3] * 3
    spec.visual.headlight.ambient = [0.15] * 3
    spec.visual.headlight.specular = [0.0] * 3
    for name, (eye, target) in _CAMERAS.items():
        q = lookat_quat(np.array(eye), np.array(target))
        world.add_camera(name=name, pos=base.pos_to_world(eye), quat=base.quat_to_world(q), fovy=50.0)
    _add_wrist_camera(robot, spec)

    # Offscreen rendering without shadows and MSAA is ~8x faster under llvmpipe (REFERENCE.md).
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.visual.global_.offwidth = max(640, int(max_camera_size[0]))
    spec.visual.global_.offheight = max(480, int(max_camera_size[1]))
    return spec, base


def attach_robot(spec: mujoco.MjSpec, robot: RobotConfig) -> None:
    """Attach the robot (compiled on its own terms) so its base body lands at base_pos/base_quat.

    Names are kept (empty prefix): robot configs, stores and runs name joints and actuators as the
    robot file does. Keyframes are dropped: they lose their meaning once objects add free joints.
    """
    child = robot.spec()
    for key in list(child.keys):
        child.delete(key)
    child.nkey = spec.nkey  # a file that sizes its keyframes (<size nkey=...>) would conflict at every compile
    if robot.gravcomp:
        for body in child.bodies:
            if body.name != "world":
                body.gravcomp = 1.0
    # The scene's physics options and visual settings win; equal ones attach without a conflict warning
    # (a robot file that sets <visual>, as gym-aloha's scenes do, would warn at every compile).
    for name in (n for n in dir(spec.option) if not n.startswith("_")):
        setattr(child.option, name, getattr(spec.option, name))
    for group in ("global_", "headlight", "map", "quality", "rgba", "scale"):
        ours, theirs = getattr(spec.visual, group), getattr(child.visual, group)
        for name in (n for n in dir(ours) if not n.startswith("_")):
            setattr(theirs, name, getattr(ours, name))
    base = base_frame(robot, child)
    target_quat = np.asarray(robot.base_quat, dtype=np.float64)
    target_quat = target_quat / np.linalg.norm(target_quat)
    # frame * base_in_robot_world = target  =>  frame = target * inverse(base_in_robot_world)
    frame_quat = quat_mul(target_quat, quat_conj(base.quat))
    frame_pos = np.asarray(robot.base_pos, dtype=np.float64) - quat_to_mat(frame_quat) @ base.pos
    frame = spec.worldbody.add_frame(pos=frame_pos.tolist(), quat=frame_quat.tolist())
    spec.attach(child, prefix="", frame=frame)


def _add_wrist_camera(robot: RobotConfig, spec: mujoco.MjSpec) -> None:
    """The ``wrist`` camera: the robot config's ``wrist_camera`` (a pose in the EE site frame, by
    default beside the hand looking past the fingertips), or the MJCF camera it names, renamed."""
    cam = robot.wrist_camera
    if isinstance(cam, str):  # load_robot checked that the MJCF has it, and no other camera is "wrist"
        spec.camera(cam).name = "wrist"
        return
    site = spec.site(robot.ee_site)
    site_quat = np.asarray(site.quat, dtype=np.float64)
    pos = np.asarray(site.pos, dtype=np.float64) + quat_to_mat(site_quat) @ np.asarray(cam.pos)
    site.parent.add_camera(name="wrist", pos=pos.tolist(), quat=quat_mul(site_quat, np.asarray(cam.quat)).tolist(),
                           fovy=cam.fovy)


def ik_spec(spec: mujoco.MjSpec, arm_joints: Sequence[str]) -> mujoco.MjSpec:
    """A copy of the scene for IK: free objects removed, every joint but the arm's frozen.

    Static and mocap geoms (table, obstacles) stay so collision limits can see them.
    """
    ik = spec.copy()
    keep = set(arm_joints)
    for body in list(ik.bodies):
        if body.name != "world" and any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in body.joints):
            ik.delete(body)
    for group in (ik.actuators, ik.tendons, ik.equalities, ik.sensors, ik.keys, ik.excludes, ik.pairs):
        for el in list(group):
            ik.delete(el)
    for joint in list(ik.joints):
        if joint.name not in keep:
            ik.delete(joint)
    return ik


def add_box_body(
    spec: mujoco.MjSpec,
    base: BaseFrame,
    name: str,
    half: Sequence[float],
    rgba: Sequence[float],
    mass: float,
    friction: Sequence[float] = (0.8, 0.01, 0.001),
) -> None:
    """A free-floating box object (its pose is part of qpos)."""
    body = spec.worldbody.add_body(name=name, pos=base.pos_to_world([0.5, 0.0, half[2]]))
    body.add_freejoint(name=f"{name}_joint")
    body.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=list(half),
        rgba=list(rgba),
        mass=mass,
        condim=4,
        friction=list(friction),
        contype=SCENE_CONTYPE,
        conaffinity=SCENE_CONAFFINITY,
    )


def add_mocap_body(spec: mujoco.MjSpec, name: str) -> mujoco.MjsBody:
    """A mocap body (goal marker, obstacle): its pose lives in mocap_pos/mocap_quat of the state."""
    return spec.worldbody.add_body(name=name, mocap=True)


def add_marker_geom(body: mujoco.MjsBody, gtype: mujoco.mjtGeom, size: Sequence[float], rgba: Sequence[float], **kw) -> None:
    """A visual-only geom (no contacts)."""
    body.add_geom(type=gtype, size=list(size), rgba=list(rgba), contype=0, conaffinity=0, mass=0.0, **kw)


def _quiet_empty_prefix() -> None:
    """Attaching with an empty prefix (names kept, see :func:`attach_robot`) makes MuJoCo warn when the
    scene first compiles, on stderr and into ``MUJOCO_LOG.TXT`` in the working directory, that such a
    model may not save to XML; `demo` never saves it, so that one warning is dropped (here for
    MuJoCo's C-level handler, in :func:`compile_scene` for the compiler's Python warning). Other
    MuJoCo warnings go on as Python warnings (or to a handler installed before)."""
    previous = mujoco.get_mju_user_warning()

    def handler(message: str) -> None:
        if "empty prefix" in message:
            return
        if previous is not None:
            previous(message)
        else:
            warnings.warn(f"MuJoCo: {message}", stacklevel=2)

    mujoco.set_mju_user_warning(handler)


def compile_scene(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """Compile a scene spec; the compiler's Python warning about the empty prefix is dropped too."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Attaching a spec with an empty prefix")
        return spec.compile()


_quiet_empty_prefix()
