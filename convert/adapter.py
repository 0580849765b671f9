"""Execute actions of any representation on an environment that takes ``joint_pos``.

A policy trained on ``ee7`` (or ``ee_abs``, ``ee_delta``, ``joint_vel``) emits one action per
control step; the adapter turns it into the environment's joint position targets + gripper:

* it keeps the last *command* (joint targets and the commanded EE pose), starting at
  :meth:`ActionAdapter.reset` from the measured state, exactly as the conversion anchors each
  episode (see :mod:`demo.convert.representations`), so a converted episode replayed through the
  adapter reproduces the original commands;
* delta actions are composed onto the last command (not onto the measured pose), and EE commands
  become joint targets by IK warm-started from the measured joints (:class:`demo.convert.ik.IKSolver`),
  one converged solve per step.

``make_adapter(spec, env)`` is what :mod:`demo.policies.actions` looks for.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from demo.convert import representations as reps
from demo.convert.ik import IKConfig, IKSolver
from demo.convert.kinematics import Kinematics
from demo.convert.representations import ActionFormat, Anchor, JointTrack
from demo.errors import DemoError
from demo.store import ActionSpec


class ActionAdapter:
    """``adapter(action) -> env action`` for one environment; call :meth:`reset` after ``env.reset``
    or ``env.set_state`` (it re-anchors on the measured state)."""

    def __init__(self, fmt: ActionFormat, env: Any, ik_config: IKConfig | None = None,
                 kin: Kinematics | None = None):
        self.fmt = fmt
        self.env = env
        robot = env.robot
        if fmt.rep.space == "joint" and len(fmt.joint_names) != robot.n_arm:
            raise DemoError("action", f"{fmt.name} has {len(fmt.joint_names)} joints; the robot has {robot.n_arm}")
        self.kin = kin or Kinematics(robot.spec().compile(), robot.arm_joints, robot.ee_site, robot.base_body,
                                     where=robot.config_path)
        self.ik = IKSolver(self.kin, ik_config) if fmt.rep.space == "ee" else None
        self.fps = float(env.fps)
        self._qadr = np.array([env.model.jnt_qposadr[env.model.joint(j).id] for j in robot.arm_joints])
        self.q_cmd = np.zeros(robot.n_arm)
        self.pos_cmd = np.zeros(3)
        self.rot_cmd = np.eye(3)
        self.steps = 0
        self.ik_failures = 0
        self.ik_max_pos_err = 0.0
        self.ik_max_rot_err = 0.0
        self.reset(env)

    def reset(self, env: Any | None = None) -> None:
        """Anchor on the measured arm joints of ``env`` (its current state)."""
        if env is not None:
            self.env = env
        q = np.array(self.env.data.qpos[self._qadr], dtype=np.float64)
        self.q_cmd = q
        pos, rot = self.kin.fk(q[None])
        self.pos_cmd, self.rot_cmd = pos[0], rot[0]

    def __call__(self, action: np.ndarray) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64).reshape(1, -1)
        anchor = Anchor(q=self.q_cmd[None], pos=self.pos_cmd[None], rot=self.rot_cmd[None])
        track = reps.decode(self.fmt, a, self.fps, anchor, where="policy action")
        if isinstance(track, JointTrack):
            q = track.q[0]
        else:
            assert self.ik is not None
            self.pos_cmd, self.rot_cmd = track.pos[0], track.rot[0]
            # Warm start from the measured joints, as the offline conversion does (see demo.convert.ik).
            q, ok, pe, re, _ = self.ik.solve(self.pos_cmd, self.rot_cmd, self.env.data.qpos[self._qadr])
            if not ok:
                self.ik_failures += 1
            self.ik_max_pos_err, self.ik_max_rot_err = max(self.ik_max_pos_err, pe), max(self.ik_max_rot_err, re)
        self.q_cmd = q
        self.steps += 1
        return np.concatenate([q, track.gripper[:1]])


def make_adapter(spec: ActionSpec, env: Any, ik_config: IKConfig | None = None) -> ActionAdapter:
    """The adapter executing actions described by ``spec`` on ``env`` (whose actions are ``joint_pos``)."""
    if env.action_spec.name != "joint_pos":
        arms = (spec.params or {}).get("arms")
        if arms:  # demo.convert.arms's each arm's ee7
            raise DemoError("env", f"the policy's actions are each arm's ee7 ({', '.join(arms)}); executing them needs "
                                   "IK per arm in the environment, which eval does not run: train on the joint-target "
                                   "store (demo convert --to ee7 --robot ARMS.toml is for exchange and inspection)")
        raise DemoError("env", f"the adapter drives joint_pos environments, not {env.action_spec.name}")
    fmt = reps.parse_spec(spec, "policy action spec", env.robot.arm_joints)
    return ActionAdapter(fmt, env, ik_config)

