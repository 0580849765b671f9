"""The simulation environment (gymnasium-style) that collect, train and eval share.

Conventions:

- Control at ``fps`` = 20 Hz: one :meth:`Env.step` applies the action and runs ``n_substeps`` = 25
  physics steps of 2 ms.
- Action (``env.action_spec``, name ``joint_pos``): the arm's joint position targets (rad, in the
  robot config's ``arm_joints`` order) followed by the gripper command, a closedness in [0, 1]
  (0 = fully open, 1 = fully closed) mapped linearly onto the gripper actuator's ``gripper_range``.
  Out-of-range targets are clipped to the actuators' ctrl ranges.
- Observations (float32): ``obs.joint_pos`` (rad), ``obs.joint_vel`` (rad/s), ``obs.gripper``
  (measured closedness, 0 open .. 1 closed), ``obs.ee_pos`` (m) and ``obs.ee_quat`` (wxyz, w >= 0)
  of the EE site in the scene frame (the robot's base frame unless its config moves the base with
  ``base_pos``/``base_quat``, see :mod:`demo.sim.scene`), then the task's (object poses ``obs.object_pos`` [K,3] /
  ``obs.object_quat`` [K,4], ``obs.goal_pos``, ...), then camera images ``obs.image_<camera>``
  (uint8 [H,W,3]). :meth:`Env.frame` adds ``sim.state`` (float64, MuJoCo integration state).
- ``step`` returns ``terminated = True`` on every step at which the task's success predicate holds
  (the env itself never stops; the caller decides when to end, e.g. a few steps after success),
  ``truncated = True`` once the episode time reaches ``horizon`` control steps, ``reward`` = 1.0 on
  success steps else 0.0, and ``info = {"success": bool}``. The step count is derived from the
  simulation time, so it survives ``set_state``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.foreign import ENV_PREFIX, ForeignEnv, is_foreign
from demo.sim.foreign_set import ForeignEnvSet, set_members
from demo.sim.geometry import canonical_f32, mat_to_quat, quat_conj, quat_mul, yaw_of
from demo.sim.numeric import clip
from demo.sim.randomize import Randomization, SceneRandomizer, corrupt_images
from demo.sim.render import parse_cameras
from demo.sim.robot import RobotConfig, arm_actuator_for, is_descendant, load_robot, position_gain
from demo.sim.robot_model import joint_limits
from demo.sim.scene import compile_scene, scene_spec
from demo.sim.task import Expert, Task
from demo.sim.tasks import TASKS
from demo.store import ActionSpec, FeatureSpec

if TYPE_CHECKING:
    from demo.sim.ik import ArmIK

CONTROL_HZ = 20.0
N_SUBSTEPS = 25
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


class Env:
    """One task scene with one robot. Create with :func:`demo.sim.make_env`."""

    def __init__(self, task: Task, robot: RobotConfig, cameras: Sequence[Any] = ()):
        self.task = task
        self.task_name = task.name
        self.task_options = dict(task.options)
        self.robot = robot
        self.cameras = parse_cameras(cameras)
        spec, self.base = scene_spec(robot, max_camera_size=self.cameras.max_size())
        task.build(spec, self.base)
        self._spec = spec
        try:
            self.model = compile_scene(spec)
        except Exception as exc:
            raise DemoError(robot.config_path, f"scene for task {task.name} does not compile: {exc}") from None
        self.data = mujoco.MjData(self.model)
        self.n_substeps = N_SUBSTEPS
        self.fps = CONTROL_HZ
        self.seed: int | None = None
        self._bind_robot()
        self._bind_views()
        self._ik: ArmIK | None = None
        self._obs_cache: tuple | None = None
        self._randomizer: SceneRandomizer | None = None
        self.randomized: dict[str, Any] = {}  # this episode's draws (demo.sim.randomize); {} when off
        self._pending: deque[np.ndarray] | None = None  # commands not yet executed (randomised latency)
        self._lag_substeps = 0  # ... and the physics substeps a new command waits within a step
        self.cameras.open(self.model)
        task.bind(self)
        self.horizon = int(task.horizon)
        self.action_spec = self._make_action_spec()
        self.reset(0)
        self.features = self._make_features()
        self.seed = None

    # ------------------------------------------------------------------ robot wiring
    def _bind_robot(self) -> None:
        m, r = self.model, self.robot
        jids = [m.joint(j).id for j in r.arm_joints]
        self.arm_qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self._arm_range = joint_limits(m, jids)  # unlimited joints are not clipped (continuous joints of 7-DOF arms)
        self.arm_dadr = np.array([m.jnt_dofadr[j] for j in jids])
        acts = [arm_actuator_for(m, j, name, r.config_path) for j, name in zip(jids, r.arm_joints)]
        self.arm_act = np.array(acts)
        gains = [position_gain(m, a, r.arm_joints[i], r.config_path) for i, a in enumerate(acts)]
        gear = m.actuator_gear[self.arm_act, 0]
        # ctrl that makes the servo settle at joint target q: gear * q = scale * ctrl + offset
        self._arm_ctrl_scale = gear / np.array([g[0] for g in gains])
        self._arm_ctrl_offset = -np.array([g[1] for g in gains]) / np.array([g[0] for g in gains])
        self._ctrl_lo = m.actuator_ctrlrange[:, 0].copy()
        self._ctrl_hi = m.actuator_ctrlrange[:, 1].copy()
        no_range = ~m.actuator_ctrllimited.astype(bool)
        self._ctrl_lo[no_range], self._ctrl_hi[no_range] = -np.inf, np.inf
        # One gripper actuator, or one per finger (robot.grippers): each gets its own (open, closed) ctrl.
        self.grip_act = np.array([m.actuator(name).id for name, _ in r.grippers])
        self._grip_open = np.array([rng[0] for _, rng in r.grippers])
        self._grip_closed = np.array([rng[1] for _, rng in r.grippers])
        gains = np.array([position_gain(m, a, name, r.config_path) for a, (name, _) in zip(self.grip_act, r.grippers)])
        self._grip_len_open = gains[:, 0] * self._grip_open + gains[:, 1]
        self._grip_len_closed = gains[:, 0] * self._grip_closed + gains[:, 1]
        self.ee_site = m.site(r.ee_site).id
        self.ee_body = int(m.site_bodyid[self.ee_site])
        # Bodies that move with the fingers: strictly below the EE site's body in the tree.
        self.finger_bodies = np.array(
            [b for b in range(m.nbody) if b != self.ee_body and is_descendant(m, b, self.ee_body)], dtype=int
        )
        self._finger_mask = np.zeros(m.nbody, dtype=bool)
        self._finger_mask[self.finger_bodies] = True
        # geom id -> the finger body it belongs to, or -1 (finger_contacts walks the few contacts in Python)
        self._finger_body_of_geom = [int(b) if self._finger_mask[b] else -1 for b in m.geom_bodyid]
        self._base_rot_t = self.base.rot.T.copy()
        self._base_is_world = not self.base.pos.any() and bool(np.array_equal(self.base.quat, [1.0, 0.0, 0.0, 0.0]))
        self._base_quat_inv = quat_conj(self.base.quat)
        self._home = {m.joint(j).id: v for j, v in r.home_qpos.items()}
        # EE pose at home: tasks take the "natural" gripper heading from it.
        scratch = mujoco.MjData(m)
        for jid, v in self._home.items():
            scratch.qpos[m.jnt_qposadr[jid]] = v
        mujoco.mj_kinematics(m, scratch)
        self.home_ee_pos = self._base_rot_t @ (scratch.site_xpos[self.ee_site] - self.base.pos)
        self.home_ee_quat = quat_mul(self._base_quat_inv, mat_to_quat(scratch.site_xmat[self.ee_site]))
        self.home_yaw = yaw_of(self.home_ee_quat)

    def _bind_views(self) -> None:
        """What every control step reads and writes, resolved once: views into ``self.data`` (its
        buffers live as long as it does), index sets as slices where they are contiguous (a view
        instead of a gather), the state size."""
        d = self.data
        self._ctrl, self._qpos, self._qvel = d.ctrl, d.qpos, d.qvel
        self._arm_q, self._arm_v = _as_slice(self.arm_qadr), _as_slice(self.arm_dadr)
        arm_ctrl, self._grip_ctrl_idx = _as_slice(self.arm_act), _as_slice(self.grip_act)
        self._ctrl_arm = d.ctrl[arm_ctrl] if isinstance(arm_ctrl, slice) else None  # a view, or None
        self._ee_xpos, self._ee_xmat = d.site_xpos[self.ee_site], d.site_xmat[self.ee_site]
        self._grip_len_span = self._grip_len_closed - self._grip_len_open
        self._one_gripper = (
            (int(self.grip_act[0]), float(self._grip_len_open[0]), float(self._grip_len_span[0]))
            if self.grip_act.shape[0] == 1 else None
        )
        self._grip_span = self._grip_closed - self._grip_open
        # One gripper actuator (most arms): its ctrl as a float, by the same IEEE operations.
        self._one_grip_ctrl = (float(self._grip_open[0]), float(self._grip_span[0])) if self.grip_act.shape[0] == 1 else None
        self._state_size = mujoco.mj_stateSize(self.model, _STATE)

    def _make_action_spec(self) -> ActionSpec:
        spec = joint_pos_action(self.robot.arm_joints)
        self._action_shape = (spec.dim,)
        return spec

    def _make_features(self) -> dict[str, FeatureSpec]:
        arm = tuple(self.robot.arm_joints)
        f = {
            "obs.joint_pos": FeatureSpec((len(arm),), "float32", "arm joint positions", "rad", arm),
            "obs.joint_vel": FeatureSpec((len(arm),), "float32", "arm joint velocities", "rad/s", arm),
            "obs.gripper": FeatureSpec((1,), "float32", "gripper closedness, measured (0 open, 1 closed)", "1"),
            "obs.ee_pos": FeatureSpec((3,), "float32", "EE site position, base frame", "m", ("x", "y", "z")),
            "obs.ee_quat": FeatureSpec((4,), "float32", "EE site orientation, base frame, w >= 0", "1", ("w", "x", "y", "z")),
        }
        f.update(self.task.features(self))
        for name, h, w in self.cameras.specs:
            f[f"obs.image_{name}"] = FeatureSpec((h, w, 3), "uint8", f"camera '{name}' RGB", "")
        n = mujoco.mj_stateSize(self.model, _STATE)
        f["sim.state"] = FeatureSpec((n,), "float64", "MuJoCo integration state (mjSTATE_INTEGRATION)", "")
        return f

    # ------------------------------------------------------------------ episode API
    def set_randomization(self, randomization: Randomization | None) -> None:
        """Draw the scene's look and physics per episode from the reset seed (:mod:`demo.sim.randomize`),
        from the next :meth:`reset` on; None: the nominal scene."""
        if self._randomizer is not None:
            self._randomizer.restore()
        active = randomization is not None and randomization.active()
        self._randomizer = SceneRandomizer(self.model, randomization) if active else None

    def reset(self, seed: int) -> dict[str, np.ndarray]:
        """Home configuration + noise, task objects and goals randomised from ``seed`` (and, with
        :meth:`set_randomization`, the scene's look and physics, from another stream of it)."""
        m, d = self.model, self.data
        self.seed = int(seed)
        self.randomized = self._randomizer.apply(self.seed) if self._randomizer is not None else {}
        self._obs_cache = None  # the same state may look different now
        rng = np.random.default_rng(self.seed)
        mujoco.mj_resetData(m, d)
        for jid, v in self._home.items():
            d.qpos[m.jnt_qposadr[jid]] = v
        q = d.qpos[self.arm_qadr] + rng.uniform(-1.0, 1.0, self.robot.n_arm) * self.task.arm_noise
        self.set_arm(q)  # forwards: task.reset sees the arm's kinematics (the gripper ctrl moves nothing yet)
        d.ctrl[self.grip_act] = self._gripper_ctrl(self.robot.home_gripper)
        self.task.reset(self, rng)
        mujoco.mj_forward(m, d)
        # Latency: whole control steps of commands held back, then substeps of the step (2 ms each).
        lag = int(round(self.randomized.get("latency", {}).get("ms", 0) / (1000.0 / self.fps / self.n_substeps)))
        steps, self._lag_substeps = divmod(lag, self.n_substeps)
        hold = np.r_[d.qpos[self.arm_qadr], self.robot.home_gripper]  # what the reset's ctrl holds
        self._pending = deque([hold] * steps) if lag else None
        return self.observe()

    def set_arm(self, q: np.ndarray) -> None:
        """Place the arm at joint positions ``q`` at rest, holding them (for resets)."""
        m, d = self.model, self.data
        lo = self._arm_range
        q = np.clip(q, lo[:, 0], lo[:, 1])
        d.qpos[self.arm_qadr] = q
        d.qvel[self.arm_dadr] = 0.0
        d.ctrl[self.arm_act] = self._arm_ctrl(q)
        mujoco.mj_forward(m, d)

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        self.advance(action)
        obs = self.observe()
        ok = self.task.success(self)
        truncated = self.steps >= self.horizon
        return obs, float(ok), ok, truncated, {"success": ok}

    def advance(self, action: np.ndarray) -> None:
        """One control step of ``action`` (``joint_pos``: arm joint targets, rad, + gripper closedness),
        physics only: :meth:`step` without observing (no camera renders), for looking ahead. Under
        randomised latency the command executed is the one given that many steps before."""
        a = np.asarray(action)  # float32 or float64: the ufuncs below compute in float64 either way
        if a.shape != self._action_shape:
            raise DemoError("action", f"expected shape ({self.action_spec.dim},), got {a.shape}")
        lag = 0  # physics substeps the previous command stays in effect (randomised latency)
        if self._pending is not None:
            self._pending.append(np.array(a, dtype=np.float64))
            a = self._pending.popleft()
            lag = self._lag_substeps
            if lag:
                mujoco.mj_step(self.model, self.data, nstep=lag)
        d, ctrl = self.data, self._ctrl
        if self._ctrl_arm is not None:  # contiguous arm actuators: their ctrl computed in place
            self._arm_ctrl(a[:-1], out=self._ctrl_arm)
        else:
            ctrl[self.arm_act] = self._arm_ctrl(a[:-1].astype(np.float64))
        ctrl[self._grip_ctrl_idx] = self._gripper_ctrl(a[-1])
        clip(ctrl, self._ctrl_lo, self._ctrl_hi, out=ctrl)
        mujoco.mj_step(self.model, d, nstep=self.n_substeps - lag)
        self.task.after_step(self)

    @property
    def steps(self) -> int:
        """Control steps since reset (from the simulation time)."""
        return int(round(self.data.time * self.fps))

    def _arm_ctrl(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Arm actuator ctrl that holds joint targets ``q`` (``out``: written there)."""
        return np.add(np.multiply(q, self._arm_ctrl_scale, out=out), self._arm_ctrl_offset, out=out)

    def _gripper_ctrl(self, closedness: float) -> np.ndarray | float:
        c = min(1.0, max(0.0, float(closedness)))
        if self._one_grip_ctrl is not None:
            open_, span = self._one_grip_ctrl
            return open_ + c * span
        return self._grip_open + c * self._grip_span

    def success(self) -> bool:
        return bool(self.task.success(self))

    @property
    def instruction(self) -> str:
        """What this episode asks for in words ("" for a task that says nothing: demo.sim.pick's ``colours``
        variants name their target)."""
        return self.task.instruction

    # ------------------------------------------------------------------ observations
    def observe(self) -> dict[str, np.ndarray]:
        """Observations of the current state (``obs.*``).

        With cameras, the last result is reused while time, qpos, qvel and the mocap poses are
        unchanged, so ``step()`` followed by ``frame()`` renders the cameras once. Without, the
        observations cost less than that check and are computed afresh.
        """
        if not self.cameras.specs:
            return self._observe()
        d = self.data
        c = self._obs_cache
        if (
            c is not None
            and c[0] == d.time
            and np.array_equal(c[1], d.qpos)
            and np.array_equal(c[2], d.qvel)
            and np.array_equal(c[3], d.mocap_pos)
            and np.array_equal(c[4], d.mocap_quat)
        ):
            return dict(c[5])
        out = self._observe()
        self._obs_cache = (d.time, d.qpos.copy(), d.qvel.copy(), d.mocap_pos.copy(), d.mocap_quat.copy(), out)
        return dict(out)

    def _observe(self) -> dict[str, np.ndarray]:
        pos, quat = self.ee_pose()
        out = {
            "obs.joint_pos": self._qpos[self._arm_q].astype(np.float32),
            "obs.joint_vel": self._qvel[self._arm_v].astype(np.float32),
            "obs.gripper": np.array([self.gripper_closedness()], dtype=np.float32),
            "obs.ee_pos": pos.astype(np.float32),
            "obs.ee_quat": canonical_f32(quat),
        }
        self.task.observe(self, out)
        if self.cameras.specs:
            self.cameras.render(self.data, out)
            if self.randomized:
                corrupt_images(out, self.randomized, self.seed, float(self.data.time))
        return out

    def frame(self, obs: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Observations plus ``sim.state`` (what a collector records per frame).

        ``obs``: the observations of the current state when the caller has them already (what
        ``step`` just returned), so they are not looked up again.
        """
        out = self.observe() if obs is None else dict(obs)
        out["sim.state"] = self.get_state()
        return out

    def gripper_closedness(self) -> float:
        if self._one_gripper is not None:  # one actuator: its value, in float arithmetic (the same IEEE operations)
            a, length_open, span = self._one_gripper
            return (float(self.data.actuator_length[a]) - length_open) / span
        length = self.data.actuator_length[self.grip_act]
        return float(((length - self._grip_len_open) / self._grip_len_span).mean())

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """EE site pose in the base frame: position (m) and quaternion (wxyz)."""
        if self._base_is_world:
            quat = np.empty(4)  # mat_to_quat of the site's (contiguous) row, without its wrapper: called every step
            mujoco.mju_mat2Quat(quat, self._ee_xmat)
            return self._ee_xpos.copy(), quat
        pos = self._base_rot_t @ (self._ee_xpos - self.base.pos)
        quat = quat_mul(self._base_quat_inv, mat_to_quat(self._ee_xmat))
        return pos, quat

    def body_pose(self, body_id: int) -> tuple[np.ndarray, np.ndarray]:
        """A body's pose in the base frame."""
        d = self.data
        if self._base_is_world:
            return d.xpos[body_id].copy(), d.xquat[body_id].copy()
        pos = self._base_rot_t @ (d.xpos[body_id] - self.base.pos)
        return pos, quat_mul(self._base_quat_inv, d.xquat[body_id])

    def mocap_pose(self, mocap_id: int) -> tuple[np.ndarray, np.ndarray]:
        """A mocap body's pose (goal marker, obstacle) in the base frame."""
        d = self.data
        if self._base_is_world:
            return d.mocap_pos[mocap_id].copy(), d.mocap_quat[mocap_id].copy()
        pos = self._base_rot_t @ (d.mocap_pos[mocap_id] - self.base.pos)
        return pos, quat_mul(self._base_quat_inv, d.mocap_quat[mocap_id])

    def set_mocap_pose(self, mocap_id: int, pos: np.ndarray, quat: np.ndarray | None = None) -> None:
        """Place a mocap body at a base-frame pose (orientation default: aligned with the base)."""
        self.data.mocap_pos[mocap_id] = self.to_world(np.asarray(pos, dtype=np.float64))
        self.data.mocap_quat[mocap_id] = self.base.quat if quat is None else self.quat_to_world(quat)

    def to_world(self, pos: np.ndarray) -> np.ndarray:
        """Base-frame position -> world."""
        if self._base_is_world:
            return np.array(pos, dtype=np.float64)
        return self.base.pos + self._base_rot_t.T @ pos

    def quat_to_world(self, quat: np.ndarray) -> np.ndarray:
        """Base-frame orientation (wxyz) -> world."""
        if self._base_is_world:
            return np.array(quat, dtype=np.float64)
        return quat_mul(self.base.quat, quat)

    def finger_contacts(self, geom_mask: np.ndarray) -> int:
        """How many distinct finger bodies touch a geom selected by the boolean ``geom_mask``."""
        finger = self._finger_body_of_geom
        touching: set[int] = set()
        for g1, g2 in self.data.contact.geom.tolist():  # a handful of contacts: a loop beats array ops
            if finger[g1] >= 0 and geom_mask[g2]:
                touching.add(finger[g1])
            if finger[g2] >= 0 and geom_mask[g1]:
                touching.add(finger[g2])
        return len(touching)

    # ------------------------------------------------------------------ state
    def get_state(self) -> np.ndarray:
        s = np.empty(self._state_size)
        mujoco.mj_getState(self.model, self.data, s, _STATE)
        return s

    def set_state(self, state: np.ndarray) -> None:
        mujoco.mj_setState(self.model, self.data, np.asarray(state, dtype=np.float64), _STATE)
        mujoco.mj_forward(self.model, self.data)

    def snapshot(self) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Everything a step reads: the integration state and the commands a latency still holds back."""
        return self.get_state(), None if self._pending is None else [a.copy() for a in self._pending]

    def restore(self, snapshot: tuple[np.ndarray, list[np.ndarray] | None]) -> None:
        state, pending = snapshot
        self.set_state(state)
        self._pending = None if pending is None else deque(pending)

    # ------------------------------------------------------------------ experts
    @property
    def spec(self) -> mujoco.MjSpec:
        """The scene's MjSpec (robot + table + task bodies) the model was compiled from; for IK models."""
        return self._spec

    @property
    def ik(self) -> ArmIK:
        """The experts' IK solver for this scene (built on first use: mink takes half a second to import,
        and replaying, viewing or describing a store never solves IK)."""
        if self._ik is None:
            from demo.sim.ik import ArmIK

            self._ik = ArmIK(self._spec, self.robot, 1.0 / self.fps, avoid_geoms=self.task.avoid_geoms)
        return self._ik

    def ik_step(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """Arm joint targets one control step toward an EE pose given in the base frame."""
        ik = self.ik
        d = self.data
        ik.set_state(self._qpos[self._arm_q], d.mocap_pos, d.mocap_quat)
        if self._base_is_world:  # ik.step only reads them: no copies
            return ik.step(pos, quat)
        return ik.step(self.to_world(pos), self.quat_to_world(quat))

    def place_ee(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Move the arm (kinematically, at rest) so the EE is at a base-frame pose; for resets."""
        d = self.data
        q = self.ik.solve_pose(d.qpos[self.arm_qadr], self.to_world(pos), self.quat_to_world(quat), d.mocap_pos, d.mocap_quat)
        self.set_arm(q)

    def expert(self, rng: np.random.Generator | None = None, **style: Any) -> Expert:
        """The task's scripted expert for the current episode (see :class:`demo.sim.task.Expert`)."""
        return self.task.expert_class(self, rng, **style)

    def close(self) -> None:
        self.cameras.close()

    def __enter__(self) -> "Env":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` as the equivalent slice when it is a contiguous increasing run, else unchanged."""
    if index.shape[0] and np.array_equal(index, np.arange(index[0], index[0] + index.shape[0])):
        return slice(int(index[0]), int(index[0]) + index.shape[0])
    return index


def joint_pos_action(arm_joints: Sequence[str]) -> ActionSpec:
    """The action the simulator takes (and collection records): arm joint targets (rad) and the gripper's
    closedness, named ``<joint>.target`` and ``gripper``."""
    return ActionSpec(
        "joint_pos",
        names=tuple(f"{j}.target" for j in arm_joints) + ("gripper",),
        units=("rad",) * len(arm_joints) + ("1",),
        frame="joint",
        description="arm joint position targets + gripper closedness (0 open, 1 closed)",
        params={"gripper": "closedness in [0, 1]: 0 = open, 1 = closed", "arm_joints": list(arm_joints)},
    )


def make_env(
    task: str,
    robot: str | Path | RobotConfig | None = None,
    cameras: Sequence[Any] = (),
    **task_options: Any,
) -> Env:
    """Build a task environment. ``robot``: None (built-in arm), a robot config path or a RobotConfig.

    ``cameras``: ``(name, width, height)`` tuples (or bare names, 128x128) from ``front``, ``side``,
    ``top``, ``wrist``; images are ``obs.image_<name>`` uint8 [height, width, 3]. Headless rendering
    uses EGL (``demo.sim`` sets ``MUJOCO_GL=egl`` when unset).
    """
    if is_foreign(task):  # any Gymnasium environment (demo.sim.foreign): it brings its own robot and cameras
        if robot is not None or cameras:
            raise DemoError(f"--env {task.removeprefix(ENV_PREFIX)}", "a Gymnasium environment brings its own robot and "
                                                                     "cameras: --robot and --camera do not apply")
        members = set_members(task)  # a named adapter's task set (metaworld:MT10): one environment per episode
        return ForeignEnvSet(task, members, **task_options) if members else ForeignEnv(task, **task_options)
    if task not in TASKS:
        raise DemoError(task, f"unknown task (known: {', '.join(TASKS)}; any Gymnasium environment: env:ID)")
    return Env(TASKS[task](**task_options), load_robot(robot), cameras)
