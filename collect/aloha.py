"""Scripted bimanual experts for gym-aloha's two tasks, by IK on both arms (mink).

``demo collect --env process:aloha_state:transfer_cube --env-opt python=GYM_ALOHA_PYTHON --expert
demo.collect.aloha:transfer_cube`` (``insertion`` alike): gym-aloha's own environment, in its own
interpreter (:mod:`demo.sim.aloha_state`, which adds the objects' poses to the observation), or the same
scene in ``demo``'s MuJoCo (``--env demo.sim.aloha_scene:transfer_cube``), driven by the expert here in
gym-aloha's action convention: 14 numbers, each arm's six joint position targets
(rad) then its gripper (gym-aloha's normalised finger opening, 0 closed, 1 open), left arm first.

The plan is ACT's (Zhao et al. 2023, its scripted policies): each arm follows waypoints of its
*tool centre point* (TCP, between the finger pads; world frame, m) and orientation, linearly
interpolated in time, and each control step solves IK for both arms from the measured joints. Two
things differ. The waypoints near an object are recomputed from the object's *current* pose at every
step until the gripper closes on it (ACT's were fixed at the first frame), and the hand-over and the
insertion aim at where the other arm's object *is*: the left hand closes on the cube where the right
hand holds it, and the peg is lined up with the socket's measured axis before it goes in. The
schedules fit gym-aloha's 300-step (6 s) episodes.

The IK model is gym-aloha's MJCF (``pip install --no-deps gym-aloha==0.1.5`` beside ``demo``: only its
files are read here, under ``demo``'s MuJoCo) with the free objects removed and the fingers frozen.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mink
import mujoco
import numpy as np

from demo.sim.aloha_scene import aloha_mjcf
from demo.sim.aloha_state import ARM_JOINTS, GRIPPER_COMMAND
from demo.sim.scene import ik_spec

ARMS = ("vx300s_left", "vx300s_right")
TCP_IN_LINK = np.array([0.1376, 0.0, 0.0117])  # m, gripper_link frame (aloha_vx300s_left.toml's ee site)
OPEN, CLOSED = GRIPPER_COMMAND  # gym-aloha's normalised gripper command
MEET = np.array([0.0, 0.5, 0.25])  # m, world: where the cube changes hands (ACT's meeting point)
INSERT_HEIGHT = 0.15  # m, world z at which peg and socket meet
HOLD_SLACK = 0.03  # m: how far the peg may have moved in the hand for the aim to follow it


def rotation(axis: str, angle: float) -> np.ndarray:
    """The 3x3 rotation by ``angle`` (rad) about the world ``axis`` (x, y or z)."""
    c, s = np.cos(angle), np.sin(angle)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def facing(arm: int, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """A gripper orientation (world frame): pointing toward the other arm (left: +x, right: -x),
    tipped down by ``pitch`` (rad) and rolled about its own axis by ``roll`` (rad)."""
    return rotation("z", np.pi * arm) @ rotation("y", pitch) @ rotation("x", roll)


class BimanualIK:
    """Both arms' joint targets (rad) for their TCP poses, by mink from the measured joints."""

    def __init__(self, mjcf: Path, posture_cost: float = 1e-3, iterations: int = 6):
        spec = mujoco.MjSpec.from_file(str(mjcf))
        names = [f"{arm}/{joint}" for arm in ARMS for joint in ARM_JOINTS]
        self.model = ik_spec(spec, names).compile()
        self.configuration = mink.Configuration(self.model)
        self.qadr = np.array([self.model.jnt_qposadr[self.model.joint(n).id] for n in names])
        self.frames = [mink.FrameTask(f"{arm}/gripper_link", "body", position_cost=1.0, orientation_cost=0.5)
                       for arm in ARMS]
        self.posture = mink.PostureTask(self.model, cost=posture_cost)
        self.limits = [mink.ConfigurationLimit(self.model)]
        self.iterations = iterations
        # The position servos' stiffness (N m / rad) per arm joint: a servo holding the arm against gravity
        # settles short of its target by gravity / kp (a few mm at the TCP with gym-aloha's soft wrists), so
        # each target is moved by that much beforehand.
        scene = spec.compile()
        kp = {scene.joint(scene.actuator_trnid[a, 0]).name: scene.actuator_gainprm[a, 0] for a in range(scene.nu)}
        self.kp = np.array([kp[n] for n in names])
        self.dof = np.array([self.model.jnt_dofadr[self.model.joint(n).id] for n in names])
        self.gravity = mujoco.MjData(self.model)

    def _qpos(self, q: np.ndarray) -> np.ndarray:
        """The IK model's qpos with both arms' 12 joints at ``q``."""
        full = self.model.qpos0.copy()
        full[self.qadr] = q
        return full

    def solve(self, q: np.ndarray, targets: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """``q``: both arms' 12 joint positions (left first); ``targets``: per arm (TCP position, 3x3
        orientation), world frame. Returns the 12 joint targets."""
        full = self._qpos(q)
        self.configuration.update(full)
        self.posture.set_target(full)  # the redundancy stays where the arm is
        for task, (tcp, rot) in zip(self.frames, targets):
            link = tcp - rot @ TCP_IN_LINK
            task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(rot), link))
        for _ in range(self.iterations):
            v = mink.solve_ik(self.configuration, [*self.frames, self.posture], 1.0, "daqp", damping=1e-4,
                              limits=self.limits)
            self.configuration.integrate_inplace(v, 1.0)
        return self.configuration.q[self.qadr].copy()

    def servo_targets(self, q: np.ndarray) -> np.ndarray:
        """The commands (rad) that hold the arms at joint positions ``q`` (12) against gravity."""
        self.gravity.qpos[:] = self._qpos(q)
        mujoco.mj_forward(self.model, self.gravity)
        return q + self.gravity.qfrc_bias[self.dof] / self.kp

    def tcp(self, q: np.ndarray) -> list[np.ndarray]:
        """Each arm's TCP position (world, m) at joint positions ``q`` (12)."""
        self.configuration.update(self._qpos(q))
        out = []
        for arm in ARMS:
            body = self.configuration.data.body(f"{arm}/gripper_link")
            out.append(body.xpos + body.xmat.reshape(3, 3) @ TCP_IN_LINK)
        return out


@dataclass(frozen=True)
class Waypoint:
    t: int  # control step (gym-aloha: 50 Hz)
    pos: np.ndarray  # TCP, world, m
    rot: np.ndarray  # 3x3, world
    grip: float  # 1 open .. 0 closed


def interpolate(plan: list[Waypoint], t: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The TCP position, orientation and gripper at step ``t`` on ``plan``: positions and gripper linear
    in time between waypoints, orientations along the shortest rotation (slerp); held after the last."""
    if t <= plan[0].t:
        return plan[0].pos, plan[0].rot, plan[0].grip
    for a, b in zip(plan, plan[1:]):
        if t <= b.t:
            f = (t - a.t) / max(b.t - a.t, 1)
            rot = a.rot if np.allclose(a.rot, b.rot) else _slerp(a.rot, b.rot, f)
            return a.pos + f * (b.pos - a.pos), rot, a.grip + f * (b.grip - a.grip)
    return plan[-1].pos, plan[-1].rot, plan[-1].grip


def _slerp(a: np.ndarray, b: np.ndarray, f: float) -> np.ndarray:
    qa, qb = mink.SO3.from_matrix(a), mink.SO3.from_matrix(b)
    return (qa @ mink.SO3.exp(f * (qa.inverse() @ qb).log())).as_matrix()


class AlohaExpert:
    """One episode's expert (``act(obs)`` at every step from the first): see the module docstring."""

    def __init__(self, task: str, ik: BimanualIK | None = None):
        self.task = task
        self.ik = ik or BimanualIK(aloha_mjcf(task))
        self.t = 0
        self.start: list[np.ndarray] | None = None  # each TCP at the first step
        self.tcp_now: list[np.ndarray] = []  # each TCP at this step
        self.held: dict[int, np.ndarray] = {}  # arm -> its object's position when its gripper closed

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        pos = np.asarray(obs["agent_pos"], dtype=np.float64)
        q = np.r_[pos[0:6], pos[7:13]]
        self.tcp_now = self.ik.tcp(q)
        if self.start is None:
            self.start = self.tcp_now
        state = np.asarray(obs["env_state"], dtype=np.float64)
        plans = self.transfer_cube(state) if self.task == "transfer_cube" else self.insertion(state)
        targets, grips = [], []
        for plan in plans:
            p, r, g = interpolate(plan, self.t)
            targets.append((p, r))
            grips.append(g)
        joints = self.ik.servo_targets(self.ik.solve(q, targets))
        self.t += 1
        return np.r_[joints[:6], grips[0], joints[6:], grips[1]].astype(np.float32)

    def _object(self, arm: int, now: np.ndarray, close_t: int) -> np.ndarray:
        """The object's position as the plan uses it: where it is until ``arm`` closes on it, then frozen."""
        if self.t < close_t:
            return now
        return self.held.setdefault(arm, now.copy())

    def transfer_cube(self, state: np.ndarray) -> list[list[Waypoint]]:
        cube = state[:3]
        pick, take = facing(1, pitch=np.radians(60)), facing(0, roll=np.radians(90))
        c = self._object(1, cube, 110)
        right = [
            Waypoint(0, self.start[1], facing(1, pitch=np.radians(10)), CLOSED),
            Waypoint(60, c + [0, 0, 0.08], pick, OPEN),
            Waypoint(90, c + [0, 0, 0.0], pick, OPEN),
            Waypoint(110, c + [0, 0, 0.0], pick, CLOSED),
            Waypoint(150, MEET + [0.05, 0, 0], pick, CLOSED),
            Waypoint(170, MEET, pick, CLOSED),
            Waypoint(225, MEET, pick, CLOSED),
            Waypoint(245, MEET, pick, OPEN),
            Waypoint(290, MEET + [0.1, 0, 0], pick, OPEN),
        ]
        meet_cube = cube if self.t >= 170 else MEET  # the left hand goes to the cube where it is held
        hand = self._object(0, meet_cube, 215) + [-0.012, 0, 0]
        left = [
            Waypoint(0, self.start[0], facing(0, pitch=np.radians(-10)), CLOSED),
            Waypoint(90, MEET + [-0.12, 0, 0], take, OPEN),
            Waypoint(170, MEET + [-0.12, 0, 0], take, OPEN),
            Waypoint(200, hand, take, OPEN),
            Waypoint(215, hand, take, CLOSED),
            Waypoint(290, hand + [-0.08, 0, 0], take, CLOSED),
        ]
        return [left, right]

    def insertion(self, state: np.ndarray) -> list[list[Waypoint]]:
        peg, socket = state[0:3], state[7:10]
        down = np.radians(60)
        grip_l, grip_r = facing(0, pitch=down), facing(1, pitch=down)
        s = self._object(0, socket, 125) + [-0.03, 0, 0]  # the socket's far half: its open end stays free
        p = self._object(1, peg, 100) + [0.01, 0, 0]  # a little toward the peg's far end
        meet = np.array([0.0, 0.5, INSERT_HEIGHT])
        left = [
            Waypoint(0, self.start[0], facing(0, pitch=np.radians(-10)), CLOSED),
            Waypoint(70, s + [0, 0, 0.08], grip_l, OPEN),
            Waypoint(100, s + [0, 0, -0.005], grip_l, OPEN),
            Waypoint(125, s + [0, 0, -0.005], grip_l, CLOSED),
            Waypoint(175, meet + [-0.13, 0, 0], grip_l, CLOSED),
        ]
        # The peg is lined up with the socket's axis where the socket is, then pushed along it. Once the
        # peg is up, the hand's targets are the peg's moved by where the hand holds it now (it hangs below
        # the TCP), within HOLD_SLACK of where it was grasped: a hand that chased a peg slipping out of
        # it would pull it further out.
        line = socket if self.t >= 175 else meet + [-0.10, 0, 0]
        grasped = p - self.held.get(1, peg)
        offset = grasped
        if self.t >= 150:
            offset = grasped + np.clip(self.tcp_now[1] - peg - grasped, -HOLD_SLACK, HOLD_SLACK)
        right = [
            Waypoint(0, self.start[1], facing(1, pitch=np.radians(10)), CLOSED),
            Waypoint(55, p + [0, 0, 0.08], grip_r, OPEN),
            Waypoint(80, p + [0, 0, -0.005], grip_r, OPEN),
            Waypoint(100, p + [0, 0, -0.005], grip_r, CLOSED),
            Waypoint(112, p + [0, 0, -0.005], grip_r, CLOSED),  # the fingers close; then a slow lift (the peg
            # slipped out of a hand that lifted within 50 steps in 6 of 100 episodes)
            Waypoint(175, line + [0.18, 0, 0] + offset, grip_r, CLOSED),
            Waypoint(205, line + [0.15, 0, 0] + offset, grip_r, CLOSED),
            Waypoint(260, line + [0.09, 0, 0] + offset, grip_r, CLOSED),
        ]
        return [left, right]


def transfer_cube(env: Any) -> AlohaExpert:
    """``--expert demo.collect.aloha:transfer_cube``: a new expert per episode."""
    return AlohaExpert("transfer_cube")


def insertion(env: Any) -> AlohaExpert:
    """``--expert demo.collect.aloha:insertion``."""
    return AlohaExpert("insertion")
