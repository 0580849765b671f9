"""gym-aloha's two tasks rebuilt in ``demo``'s MuJoCo from gym-aloha's own MJCF, with the simulator at hand.

gym-aloha's environment (:mod:`demo.sim.aloha_state`) runs in its own interpreter, on MuJoCo 3.8 and
dm_control, so its simulator state never reaches ``demo``. This is the same scene in this interpreter:
gym-aloha's MJCF (``pip install --no-deps gym-aloha==0.1.5``: its files only), its reset draw (the
same ``numpy.random.RandomState(seed)`` draw of the objects' positions), its 14-D action (each arm's six
joint position targets, rad, then its gripper normalised 0 closed .. 1 open, left arm first), its 50 Hz
control (10 physics steps of 2 ms), its ``agent_pos`` and ``env_state`` and its reward by contacts, success
at reward 4. What it adds is the simulator: :meth:`AlohaScene.get_state` / :meth:`set_state` save and
restore it exactly, for looking ahead, viewing and curation signals.

Build it as ``--env demo.sim.aloha_scene:transfer_cube`` (or ``:insertion``); the experts of
:mod:`demo.collect.aloha` drive it as they drive gym-aloha. MuJoCo 4 is not MuJoCo 3.8, so trajectories
are close, not identical (``docs/environments.md`` gives the experts' success in both).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import gymnasium
import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.aloha_state import ACTION_NAMES, ACTION_UNITS, ARM_QPOS, GRIPPER_COMMAND, flag
from demo.sim.render import CameraSet

MJCF = {"transfer_cube": "bimanual_viperx_transfer_cube.xml", "insertion": "bimanual_viperx_insertion.xml"}
START_ARM_QPOS = np.array([0, -0.96, 1.16, 0, -0.3, 0, 0.02239, -0.02239] * 2)  # gym-aloha's START_ARM_POSE
FINGER_OPEN, FINGER_CLOSED = 0.058, 0.01844  # m: gym-aloha's PUPPET_GRIPPER_POSITION_OPEN / _CLOSE
DT, SUBSTEPS = 0.02, 10  # s per control step, physics steps per control step
MAX_EPISODE_STEPS = 300  # gym-aloha's registration
LEFT_FINGER, RIGHT_FINGER = "vx300s_left/10_left_gripper_finger", "vx300s_right/10_right_gripper_finger"
SOCKET = ("socket-1", "socket-2", "socket-3", "socket-4")


def aloha_mjcf(task: str) -> Path:
    """gym-aloha's MJCF of ``task`` from the installed package (its files only; nothing is imported)."""
    spec = importlib.util.find_spec("gym_aloha")
    if spec is None or not spec.submodule_search_locations:
        raise DemoError("gym-aloha", "is not installed beside demo (pip install --no-deps gym-aloha==0.1.5): "
                        "its MJCF is read for the bimanual scene and the experts' IK")
    if task not in MJCF:
        raise DemoError("gym-aloha", f"no task {task!r} (known: {', '.join(MJCF)})")
    return Path(list(spec.submodule_search_locations)[0]) / "assets" / MJCF[task]


def finger_position(normalised: np.ndarray | float) -> np.ndarray:
    """gym-aloha's gripper command (0 closed .. 1 open) -> the finger joint's position target (m)."""
    return np.asarray(normalised) * (FINGER_OPEN - FINGER_CLOSED) + FINGER_CLOSED


def normalised_gripper(finger: np.ndarray | float) -> np.ndarray:
    """A finger joint's position (m) -> gym-aloha's normalised gripper reading."""
    return (np.asarray(finger) - FINGER_CLOSED) / (FINGER_OPEN - FINGER_CLOSED)


def initial_poses(task: str, seed: int | None) -> np.ndarray:
    """The free objects' initial qpos, drawn as gym-aloha draws them from the reset seed (its ``utils``):
    transfer cube, the cube at x in [0, 0.2], y in [0.4, 0.6]; insertion, the peg at x in [0.1, 0.2] then
    the socket at x in [-0.2, -0.1] (same y range); z 0.05, upright."""
    rng = np.random.RandomState(seed)
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    if task == "transfer_cube":
        return np.r_[rng.uniform([0.0, 0.4, 0.05], [0.2, 0.6, 0.05]), identity]
    peg = rng.uniform([0.1, 0.4, 0.05], [0.2, 0.6, 0.05])
    socket = rng.uniform([-0.2, 0.4, 0.05], [-0.1, 0.6, 0.05])
    return np.r_[peg, identity, socket, identity]


class AlohaScene(gymnasium.Env):
    """gym-aloha's ``task`` (module docstring). Observation: ``agent_pos`` (14) and ``env_state`` (the objects'
    poses: 7 per object, world frame, position m then quaternion wxyz); with ``pixels``, ``pixels.top`` too, the
    top camera at ``width`` x ``height`` (uint8 [H, W, 3]), laid out as gym-aloha's ``pixels_agent_pos`` (so a
    store's features are named alike: ``obs.image_pixels_top``)."""

    metadata = {"render_modes": [], "render_fps": int(round(1 / DT))}

    def __init__(self, task: str = "transfer_cube", max_episode_steps: int = MAX_EPISODE_STEPS, pixels: bool = False,
                 width: int = 640, height: int = 480):
        self.task = task
        self.model = mujoco.MjModel.from_xml_path(str(aloha_mjcf(task)))
        self.data = mujoco.MjData(self.model)
        self.model.opt.timestep = DT / SUBSTEPS  # gym-aloha's files say so too; kept explicit
        self.max_episode_steps = int(max_episode_steps)
        self.horizon = self.max_episode_steps
        objects = 7 if task == "transfer_cube" else 14
        spaces: dict[str, gymnasium.Space] = {
            "agent_pos": gymnasium.spaces.Box(-1000.0, 1000.0, (14,), np.float64),
            "env_state": gymnasium.spaces.Box(-10.0, 10.0, (objects,), np.float64),
        }
        self.cameras = CameraSet([("top", int(height), int(width))] if pixels else [])
        if pixels:
            spaces["pixels"] = gymnasium.spaces.Dict({"top": gymnasium.spaces.Box(0, 255, (int(height), int(width), 3),
                                                                                   np.uint8)})
            self.cameras.open(self.model)
        self.observation_space = gymnasium.spaces.Dict(spaces)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (14,), np.float32)
        self.action_names, self.action_units = ACTION_NAMES, ACTION_UNITS
        self.gripper_command = GRIPPER_COMMAND
        self._geoms = {name: mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name)
                       for name in ("red_box", "red_peg", "pin", "table", LEFT_FINGER, RIGHT_FINGER, *SOCKET)}
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:ARM_QPOS] = START_ARM_QPOS
        self.data.ctrl[:] = START_ARM_QPOS
        self.data.qpos[ARM_QPOS:] = initial_poses(self.task, seed)
        mujoco.mj_forward(self.model, self.data)
        self.t = 0
        return self._obs(), {"is_success": False}

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        a = np.asarray(action, dtype=np.float64)
        left, right = finger_position(a[6]), finger_position(a[13])
        self.data.ctrl[:] = np.r_[a[0:6], left, -left, a[7:13], right, -right]
        mujoco.mj_step(self.model, self.data, nstep=SUBSTEPS)
        self.t += 1
        reward = float(self.reward())
        success = reward == 4
        return self._obs(), reward, success, self.t >= self.max_episode_steps, {"is_success": success}

    def reward(self) -> int:
        """gym-aloha's reward (0..4) from this step's contacts."""
        pairs = {frozenset((int(c.geom1), int(c.geom2))) for c in self.data.contact[: self.data.ncon]}
        g = self._geoms

        def touching(a: str, b: str | tuple[str, ...]) -> bool:
            return any(frozenset((g[a], g[o])) in pairs for o in ((b,) if isinstance(b, str) else b))

        if self.task == "transfer_cube":
            left, right, table = touching("red_box", LEFT_FINGER), touching("red_box", RIGHT_FINGER), touching("red_box", "table")
            return 4 if left and not table else 3 if left else 2 if right and not table else 1 if right else 0
        both = touching("red_peg", RIGHT_FINGER) and any(touching(s, LEFT_FINGER) for s in SOCKET)
        lifted = not touching("red_peg", "table") and not any(touching(s, "table") for s in SOCKET)
        if touching("red_peg", "pin"):
            return 4
        if touching("red_peg", SOCKET) and lifted:
            return 3
        return 2 if both and lifted else 1 if both else 0

    def get_state(self) -> np.ndarray:
        """The simulator state (MuJoCo's integration state: physics, controls, solver warm start) with the step count:
        restorable exactly."""
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(self.model, spec))
        mujoco.mj_getState(self.model, self.data, state, spec)
        return np.r_[state, self.t]

    def set_state(self, state: np.ndarray) -> None:
        mujoco.mj_setState(self.model, self.data, np.asarray(state[:-1], dtype=np.float64), mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(self.model, self.data)
        self.t = int(state[-1])

    def close(self) -> None:
        self.cameras.close()

    def _obs(self) -> dict[str, Any]:
        q = self.data.qpos
        grips = normalised_gripper(q[[6, 14]])
        obs: dict[str, Any] = {"agent_pos": np.r_[q[0:6], grips[0], q[8:14], grips[1]].astype(np.float64),
                               "env_state": q[ARM_QPOS:].astype(np.float64).copy()}
        if self.cameras.specs:
            images: dict[str, np.ndarray] = {}
            self.cameras.render(self.data, images)
            obs["pixels"] = {"top": images["obs.image_top"]}
        return obs


def transfer_cube(max_episode_steps: int = MAX_EPISODE_STEPS, pixels: bool | str = False, width: int = 640,
                  height: int = 480) -> AlohaScene:
    """``--env demo.sim.aloha_scene:transfer_cube [--env-opt pixels=true --env-opt width=W --env-opt height=H]``."""
    return AlohaScene("transfer_cube", int(max_episode_steps), flag(pixels), int(width), int(height))


def insertion(max_episode_steps: int = MAX_EPISODE_STEPS, pixels: bool | str = False, width: int = 640,
              height: int = 480) -> AlohaScene:
    """``--env demo.sim.aloha_scene:insertion`` (options as :func:`transfer_cube`)."""
    return AlohaScene("insertion", int(max_episode_steps), flag(pixels), int(width), int(height))
