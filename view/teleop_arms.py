"""`demo teleop --mode leader --env ENV --robot ARMS.toml`: the leader arms of a robot of several arms (ALOHA's
pair in :mod:`demo.sim.aloha_scene`), moved live in the browser, followed by the simulated arms, recorded.

The page shows the scene (:class:`demo.view.scene.MujocoScene`), one translucent ghost per leader arm at the
leaders' joints, a folder of sliders per arm (its joints in rad within their ranges, named as the action names
them, ``left.waist`` ...; its gripper as closedness, 0 open .. 1 closed), **Start** / **Stop & save** /
**Discard**, a status line with the tracking error (the largest gap between a leader joint and its follower, mrad)
and the follower's ``top`` camera. At the environment's control rate the followers' servos are commanded the
leaders' positions (joints, and each gripper's closedness as the environment's ``gripper_command``), and that
command is the recorded action, as ``demo collect --source leader`` records a leader file
(:mod:`demo.collect.leader_arms`): the same keys and episode columns, so the two kinds of episodes mix in a store.

Episode ``i`` starts from ``env.reset(episode_seed(seed, i))`` with the leaders at the followers' measured
joints; it is appended atomically on **Stop & save**, and saved by itself when it reaches the environment's
horizon (gym-aloha's: 300 steps, 6 s). The server listens on 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from demo.collect.human import HumanConfig, InputEpisode, episode_info, human_store_meta
from demo.collect.leader_arms import LeaderArms
from demo.collect.scripted import make_env_for
from demo.errors import DemoError
from demo.seeds import episode_seed
from demo.sim.arms import MEASURED_KEY, closedness_from_gripper, gripper_from_closedness, load_arms
from demo.sim.foreign import task_name
from demo.sim.robot_model import is_descendant
from demo.store.output import open_output
from demo.view.scene import MujocoScene
from demo.view.teleop import LiveSession

FOLLOWER_VIEW = ("top", 120, 160)  # the follower's camera on the page (name, height, width)
FOLLOWER_VIEW_EVERY = 5  # control steps between two renders of it


@dataclass
class ArmsLeaderConfig:
    env: str  # a Gymnasium environment whose action is the arms' joint targets (demo.sim.aloha_scene:TASK)
    robot: str  # the robot of several arms (ARMS.toml)
    out: str | None = None  # store to append episodes to (created if missing); None: nothing saved
    seed: int = 0
    operator: str = "human"
    host: str = "127.0.0.1"
    port: int = 8080  # 0: any free port
    verbose: bool = False


class ArmsLeaderSession(LiveSession):
    """A live page of leader arms and the simulation that follows them. ``close()`` stops both (and saves nothing)."""

    def __init__(self, config: ArmsLeaderConfig, *, run_thread: bool = True):
        self.config = config
        self.leaders = LeaderArms(load_arms(config.robot))
        self.arms = self.leaders.arms
        self.human = HumanConfig(task=task_name(config.env), source="leader", input="teleop", seed=config.seed,
                                 operator=config.operator, robot=config.robot, settings={"leader": "live (demo teleop)"})
        self.env = make_env_for(self.human.collect_config())
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._syncing = False
        self._renderer: mujoco.Renderer | None = None  # made and closed in the simulation thread (its GL context)
        self.store, self.server, self._thread = None, None, None
        self.saved = 0
        try:
            where = f"--env {config.env}"
            self.gripper_command = self.arms.check_env(self.env, where)
            sim = self.env.gym.unwrapped
            if not isinstance(getattr(sim, "model", None), mujoco.MjModel):
                raise DemoError(where, "has no MuJoCo model in this process to draw (a leader file, --source leader, "
                                       "works with any environment)")
            self.model, self.data = sim.model, sim.data
            self._qadr = np.array([self.model.jnt_qposadr[self.model.joint(j).id]
                                   for arm in self.arms.arms for j in arm.arm_joints])
            if config.out is not None:
                self.store = open_output(config.out, human_store_meta(self.human, self.env), True, False)
            self.episode_index, self.recording, self.moved, self.status_note = 0, False, False, ""
            self.tracking_error = 0.0
            self._enabled: dict[str, bool] = {}
            self._reset_episode()
            self._open_page("demo teleop (leader arms)", self.model)
        except BaseException:
            self.close()
            raise
        if run_thread:
            self._start_thread()

    # ------------------------------------------------------------------ page
    def _build_page(self) -> None:
        server, gui = self.server, self.server.gui
        server.initial_camera.position, server.initial_camera.look_at = (-0.15, -0.75, 0.45), (-0.1, 0.0, 0.3)
        gui.add_markdown(f"**demo teleop**: leader arms of {self.arms.name}, {self.config.env}")
        self.buttons = {name: gui.add_button(label) for name, label in
                        (("start", "Start"), ("stop", "Stop & save"), ("discard", "Discard"))}
        for name, button in self.buttons.items():
            button.on_click(lambda event, name=name: self.press(name))
        self.status = gui.add_markdown(self._status_text())
        bodies = {int(self.model.jnt_bodyid[self.model.joint(j).id]) for arm in self.arms.arms for j in arm.arm_joints}
        ghost = {b for b in range(self.model.nbody) if b in bodies or any(is_descendant(self.model, b, a) for a in bodies)}
        self.ghost = MujocoScene(server.scene, self.model, root="/leader", only_bodies=ghost, opacity=0.35)
        self._ghost_data = mujoco.MjData(self.model)
        self.sliders: list[Any] = []  # the action's dimensions, in order: each arm's joints, then its gripper
        limits = np.where(np.isfinite(self.leaders.limits), self.leaders.limits, np.array([[-np.pi, np.pi]]))
        joint = 0
        for arm_name, part in zip(self.arms.arm_names, self.arms.arm_slices()):
            with gui.add_folder(f"leader {arm_name}"):
                for i in range(part.start, part.stop):
                    name = self.arms.action_names[i]
                    if name.endswith(".gripper"):
                        low, high, step = 0.0, 1.0, 0.01
                    else:
                        (low, high), step = limits[joint], 0.001
                        joint += 1
                    slider = gui.add_slider(name, min=float(low), max=float(high), step=step,
                                            initial_value=float(np.clip(self.leader[i], low, high)))
                    slider.on_update(lambda event, i=i: self._on_slider(i))
                    self.sliders.append(slider)
        name, height, width = FOLLOWER_VIEW
        self.follower_view = gui.add_image(np.zeros((height, width, 3), np.uint8), label=f"follower: {name} camera")
        self._view_steps = 0

    def _on_slider(self, i: int) -> None:
        with self._lock:
            if not self._syncing:
                self.leader[i] = float(self.sliders[i].value)
                self.moved |= self.recording

    def allowed(self) -> dict[str, bool]:
        """Which buttons the current state allows (the page disables the others; :meth:`press` ignores them)."""
        with self._lock:
            return {"start": not self.recording, "stop": self.recording and self.moved and self.store is not None,
                    "discard": self.recording}

    def _status_text(self) -> str:
        state = f"recording, frame {len(self._frames)}" if self.recording else "idle (press Start to record)"
        note = f" · {self.status_note}" if self.status_note else ""
        return (f"episode {self.episode_index} · {state} · saved {self.saved} · tracking error "
                f"{1000 * self.tracking_error:.1f} mrad{note}")

    def _show(self) -> None:
        self.scene.show_data(self.data)
        self._ghost_data.qpos[:] = self.data.qpos
        self._ghost_data.qpos[self._qadr] = self.leader[self.arms.joint_dims()]
        mujoco.mj_kinematics(self.model, self._ghost_data)
        self.ghost.show_data(self._ghost_data)
        if self._leader_set:  # moved by code (set_leader, a new episode), not by its sliders: they follow it
            self._leader_set = False
            self._syncing = True  # setting a slider's value calls its on_update: not a person's move
            try:
                for slider, value in zip(self.sliders, self.leader):
                    if abs(float(slider.value) - float(value)) > 5e-4:
                        slider.value = float(value)
            finally:
                self._syncing = False
        self.status.content = self._status_text()
        self._update_buttons()

    def _render_follower_view(self) -> None:
        self._view_steps += 1
        if self._view_steps % FOLLOWER_VIEW_EVERY != 1:
            return
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, *FOLLOWER_VIEW[1:])
        self._renderer.update_scene(self.data, camera=FOLLOWER_VIEW[0])
        self.follower_view.image = self._renderer.render()

    # ------------------------------------------------------------------ controls (thread-safe)
    def set_leader(self, leader: np.ndarray) -> None:
        """Put the leaders at ``leader``: the action's layout, each arm's joints (rad) then its gripper's closedness
        (0 open .. 1 closed), as the sliders do."""
        with self._lock:
            self.leader[:] = np.asarray(leader, dtype=np.float64)
            self._leader_set = True
            self.moved |= self.recording

    # ------------------------------------------------------------------ episodes and simulation
    def _action(self) -> np.ndarray:
        """The environment's action from the leaders: joints clipped to their ranges, closedness as gripper command."""
        action = self.leader.copy()
        joints, grippers = self.arms.joint_dims(), self.arms.gripper_dims()
        action[joints] = np.clip(action[joints], self.leaders.limits[:, 0], self.leaders.limits[:, 1])
        action[grippers] = gripper_from_closedness(np.clip(action[grippers], 0.0, 1.0), self.gripper_command)
        return action.astype(np.float32)

    def _reset_episode(self) -> None:
        self.seed = episode_seed(self.config.seed, self.episode_index)
        self.env.reset(self.seed)
        self.leader = self.env.frame()[MEASURED_KEY].astype(np.float64)  # the leaders start at the followers
        grippers = self.arms.gripper_dims()
        self.leader[grippers] = np.clip(closedness_from_gripper(self.leader[grippers], self.gripper_command), 0.0, 1.0)
        self._leader_set = True
        self._frames: list[dict[str, np.ndarray]] = []
        self._first_success: int | None = None
        self.moved = False

    def step(self) -> None:
        """One control step: the followers commanded the leaders' positions, physics, recording, page update."""
        with self._lock:
            frame = self.env.frame() if self.recording else None
            action = self._action()
            _, _, success, _, _ = self.env.step(action)
            joints = self.arms.joint_dims()
            self.tracking_error = float(np.abs(self.env.frame()[MEASURED_KEY][joints] - action[joints]).max())
            if frame is not None:
                frame["action"] = frame["info.executed_action"] = action
                frame["info.ee_target"] = np.zeros(7, np.float32)  # no EE target: the leaders give joints
                self._frames.append(frame)
                if self._first_success is None and success:
                    self._first_success = len(self._frames)
                if len(self._frames) >= self.env.horizon:
                    self.status_note = "reached the environment's horizon"
                    self._finish(save=True)
            self._show()
            self._render_follower_view()

    def _finish(self, save: bool) -> None:
        if not self.recording:
            return
        self.recording = False
        if save and self._frames and self.store is not None:
            data = {k: np.stack([f[k] for f in self._frames]) for k in self._frames[0]}
            ok = np.ones((len(self._frames), 1), dtype=bool)  # the sliders stay within the joints' ranges
            data["info.ik_ok"], data["info.ik_error"] = ok, np.zeros((len(self._frames), 2), np.float32)
            info = episode_info(self.human, InputEpisode(-1, self.seed, None), self.seed, self._first_success is not None,
                                self._first_success, ok)
            self.store.append_episode(data, **info)
            self.saved += 1
            self.status_note = f"saved episode ({len(self._frames)} frames, success {info['success']})"
        else:
            self.status_note = "discarded" if not save else "nothing saved (no --out)"
        self.episode_index += 1
        self._reset_episode()
