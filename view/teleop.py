"""`demo teleop`: live teleoperation in the browser (viser), recorded into a store.

The page shows the task scene (drawn by :class:`demo.view.scene.MujocoScene`), a transform gizmo
and a panel with **Start** (reset to the next episode's initial state and record), **Stop & save**,
**Discard**, **Open gripper** / **Close gripper** and a status line. A button is enabled only when
the current state allows it (:meth:`TeleopSession.allowed`): Start while not recording, Stop & save
once the recording has some motion in it (the hand moved or the gripper was used) and there is a
store to save to, Discard while recording, Open/Close when the gripper is not already so. The
simulation runs in real time at the control rate in a background thread.

Modes:

- ``vr``: the gizmo is the tracked hand, already in the robot's frame (what ``collect_vr`` gets
  after calibration and scaling); :class:`demo.collect.retarget.Retargeter` (mink or placo) turns
  it into joint targets every control step. Unreached hand poses are flagged (``info.ik_ok``) and
  shown in the status line.
- ``kinesthetic``: the arm is backdrivable: gravity is compensated (the robot's gravcomp), the arm
  servos are softened (gains times ``soft_gain``) and re-targeted to the measured joints every
  physics step, so they only damp, and a damped spring (``spring_*``) pulls the EE site toward
  the gizmo, the point the person drags. The recorded action is the configuration the arm reached
  one control step later (the label ``collect_kinesthetic`` uses).

- ``leader``: leader-follower (ALOHA). The person moves a leader arm, a kinematic copy of the robot
  shown as a ghost: by its joint sliders, or by the gizmo on its hand (IK on the leader's own
  configuration, which persists between steps). The follower, the simulated robot, is commanded the
  leader's joint positions through its position servos at the control rate, and the leader's joint
  positions are the recorded action. The status line shows the tracking error (the largest joint gap
  between the leader and the follower, mrad), and the panel the follower's ``front`` camera.

Episodes are stored like ``collect_kinesthetic`` / ``collect_vr`` episodes (same keys, ``source``
= the mode, ``operator``, ``unreachable_frames``), each appended atomically on **Stop & save**.
The server listens on 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from demo.collect.human import HumanConfig, InputEpisode, episode_info, human_store_meta
from demo.store.output import open_output
from demo.collect.retarget import IK_BACKENDS, Retargeter
from demo.collect.scripted import make_env_for
from demo.errors import DemoError
from demo.seeds import episode_seed
from demo.sim.geometry import quat_conj, quat_mul
from demo.view.scene import MujocoScene

MODES = ("kinesthetic", "vr", "leader")
FOLLOWER_VIEW = ("front", 120, 160)  # leader mode: the follower's camera shown on the page (name, height, width)
FOLLOWER_VIEW_EVERY = 5  # control steps between two renders of it
LEADER_AT_HAND_M, LEADER_AT_HAND_RAD = 0.001, 0.01  # leader mode: its hand has reached the gizmo
CAMERA_EYE, CAMERA_LOOK_AT = (1.15, -0.85, 0.7), (0.4, 0.0, 0.15)  # base frame, m


@dataclass
class TeleopConfig:
    mode: str = "vr"
    task: str = "pick"
    out: str | None = None  # store to append episodes to (created if missing); None: nothing saved
    seed: int = 0  # episode i starts from env.reset(episode_seed(seed, i))
    operator: str = "human"
    robot: str | None = None
    task_options: dict[str, Any] = field(default_factory=dict)
    ik: str = "mink"
    host: str = "127.0.0.1"
    port: int = 8080  # 0: any free port
    max_episode_s: float = 120.0  # recording stops (and is kept) after this long
    soft_gain: float = 0.01  # kinesthetic: arm servo stiffness factor (damping scales with its sqrt)
    spring_stiffness: float = 400.0  # N/m, gizmo -> EE site
    spring_damping: float = 60.0  # N s/m
    spring_rot_stiffness: float = 8.0  # N m/rad
    spring_rot_damping: float = 0.8  # N m s/rad
    verbose: bool = False


class LiveSession:
    """What every live page shares: its viser server, its store, its environment and the real-time thread that
    steps it (``step()``, at the environment's control rate), with the camera renderer that thread owns.
    A subclass sets ``env``, ``server``, ``store``, ``config`` (its ``verbose``) and ``saved``."""

    env: Any
    server: Any
    store: Any
    config: Any
    saved: int
    recording: bool
    status_note: str
    buttons: dict[str, Any]
    _enabled: dict[str, bool]
    _lock: threading.RLock
    _thread: threading.Thread | None
    _stop: threading.Event
    _renderer: mujoco.Renderer | None

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    def _open_page(self, label: str, model: mujoco.MjModel) -> None:
        """Serve the page (``config.host``, ``config.port``): the scene of ``model``, the subclass's panel
        (``_build_page``), the first picture (``_show``)."""
        import viser  # deferred: heavy dependency (viser)

        with _quiet(not self.config.verbose):
            self.server = viser.ViserServer(host=self.config.host, port=self.config.port, label=label,
                                            verbose=self.config.verbose)
        self.scene = MujocoScene(self.server.scene, model)
        self._build_page()
        self._show()

    def press(self, name: str) -> None:
        """What a button does: start, stop (save), discard, and the subclass's own (:meth:`_control`); a control
        the state does not allow (see the subclass's ``allowed()``) does nothing but say so in the status line."""
        with self._lock:
            allowed = self.allowed()
            if name not in allowed:
                raise ValueError(f"unknown control {name!r}")
            if not allowed[name]:
                self.status_note = f"{self.buttons[name].label}: not now"
            elif name == "start":
                self._reset_episode()
                self.recording = True
                self.status_note = ""
            elif name in ("stop", "discard"):
                self._finish(save=name == "stop")
            else:
                self._control(name)
            self._update_buttons()

    def _control(self, name: str) -> None:
        """A control of the subclass's own (none here)."""
        raise ValueError(f"unknown control {name!r}")

    def _update_buttons(self) -> None:
        """The page's buttons enabled as the subclass's ``allowed()`` says."""
        allowed = self.allowed()
        for name, enabled in allowed.items():
            if self._enabled.get(name) != enabled:  # only changes go over the websocket
                self.buttons[name].disabled = not enabled
        self._enabled = allowed


    def _start_thread(self) -> None:
        self._thread = threading.Thread(target=self._run, name="demo-teleop-sim", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            realtime_loop(self, self.env.fps, self._stop)
        finally:
            if self._renderer is not None:  # closed in the thread that made its OpenGL context
                self._renderer.close()
                self._renderer = None

    def close(self) -> None:
        """Stop the simulation and the server; an episode being recorded is discarded."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        if self.server is not None:
            with _quiet(not self.config.verbose):
                self.server.stop()
            self.server = None
        if self.store is not None:
            # Stopped before a first episode, a store created here goes (abandon: nothing published;
            # a store appended to keeps what it held): a collection is invisible until it records.
            if self.saved:
                self.store.close()
            else:
                self.store.abandon()
            self.store = None
        self.env.close()

    def __enter__(self) -> "LiveSession":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TeleopSession(LiveSession):
    """A live teleoperation page and its simulation. ``close()`` stops both (and saves nothing)."""

    def __init__(self, config: TeleopConfig, *, run_thread: bool = True):
        if config.mode not in MODES:
            raise DemoError("--mode", f"unknown mode {config.mode!r} (choose from {', '.join(MODES)})")
        if config.ik not in IK_BACKENDS:
            raise DemoError("--ik", f"unknown IK backend {config.ik!r} (choose from {', '.join(IK_BACKENDS)})")
        self.config = config
        self.human = HumanConfig(
            task=config.task, source=config.mode, input="teleop", seed=config.seed, operator=config.operator,
            robot=config.robot, task_options=dict(config.task_options),
            settings={"soft_gain": config.soft_gain} if config.mode == "kinesthetic" else {"ik": config.ik},
        )
        self.env = make_env_for(self.human.collect_config())
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._syncing = False
        self._renderer: mujoco.Renderer | None = None  # leader mode: the follower's camera (made in the simulation thread)
        self.store = None
        self.saved = 0  # before the store opens: close() reads it
        self.server = None
        self._thread: threading.Thread | None = None
        try:
            if config.out is not None:
                self.store = open_output(config.out, human_store_meta(self.human, self.env), True, False)
            # vr: the IK turns the hand into joint targets; leader: the IK moves the leader arm, whose
            # configuration (the retargeter's own, persisting between steps) is the follower's target.
            self.retargeter = Retargeter(self.env, config.ik) if config.mode != "kinesthetic" else None
            self.tracking_error = 0.0  # leader: max |leader - follower| over the arm joints (rad)
            self._sliders_moved = self._gizmo_moved = False
            if config.mode == "kinesthetic":
                self._soften_arm(config.soft_gain)
            self.episode_index = 0
            self.grip = 0.0
            self.recording = False
            self.moved = False  # the hand moved or the gripper was used since Start: something to save
            self._enabled: dict[str, bool] = {}  # the buttons' enabled state as last sent to the page
            self._frames: list[dict[str, np.ndarray]] = []
            self._ok: list[bool] = []
            self._err: list[tuple[float, float]] = []
            self._first_success: int | None = None
            self.last_ok = True
            self.status_note = ""
            self._reset_episode()
            self._open_page(f"demo teleop ({config.mode})", self.env.model)
        except BaseException:
            self.close()
            raise
        if run_thread:
            self._start_thread()

    # ------------------------------------------------------------------ page
    def _build_page(self) -> None:
        server = self.server
        pos, quat = self._ee_world()
        self.gizmo = server.scene.add_transform_controls(
            "/hand", scale=0.18, position=pos, wxyz=quat, depth_test=False, disable_rotations=self.config.mode == "kinesthetic"
        )
        self.gizmo.on_update(lambda event: self._on_gizmo())
        # Over the table from the front-right, like the sim's "front" camera but closer.
        server.initial_camera.position = tuple(self.env.to_world(np.array(CAMERA_EYE)))
        server.initial_camera.look_at = tuple(self.env.to_world(np.array(CAMERA_LOOK_AT)))
        gui = server.gui
        gui.add_markdown(f"**demo teleop**: {self.config.mode}, task {self.config.task}")
        self.buttons = {
            "start": gui.add_button("Start"),
            "stop": gui.add_button("Stop & save"),
            "discard": gui.add_button("Discard"),
            "open": gui.add_button("Open gripper"),
            "close": gui.add_button("Close gripper"),
        }
        for name, button in self.buttons.items():
            button.on_click(lambda event, name=name: self.press(name))
        self.status = gui.add_markdown(self._status_text())
        self.sliders: list[Any] = []
        if self.config.mode == "leader":
            self._build_leader_panel(server)

    def _build_leader_panel(self, server: Any) -> None:
        """The leader arm: a ghost of the robot at the leader's configuration, one slider per joint, and the
        follower's camera."""
        from demo.sim.robot_model import is_descendant, joint_limits

        env = self.env
        arm_bodies = {int(env.model.jnt_bodyid[env.model.joint(j).id]) for j in env.robot.arm_joints}
        robot = {b for b in range(env.model.nbody) if b in arm_bodies or any(is_descendant(env.model, b, a) for a in arm_bodies)}
        self.ghost = MujocoScene(server.scene, env.model, root="/leader", only_bodies=robot, opacity=0.35)
        self._ghost_data = mujoco.MjData(env.model)
        limits = joint_limits(env.model, [env.model.joint(j).id for j in env.robot.arm_joints])
        limits = np.where(np.isfinite(limits), limits, np.array([[-np.pi, np.pi]]))
        folder = server.gui.add_folder("leader arm")
        with folder:
            for j, name in enumerate(env.robot.arm_joints):
                slider = server.gui.add_slider(name, min=float(limits[j, 0]), max=float(limits[j, 1]), step=0.001,
                                               initial_value=float(np.clip(self.retargeter.q[j], *limits[j])))
                slider.on_update(lambda event, j=j: self._on_slider(j))
                self.sliders.append(slider)
        name, height, width = FOLLOWER_VIEW
        self.follower_view = server.gui.add_image(np.zeros((height, width, 3), np.uint8), label=f"follower: {name} camera")
        self._view_steps = 0

    def _on_slider(self, j: int) -> None:
        """A leader joint moved by its slider: the leader's configuration, and its hand (the gizmo) with it."""
        with self._lock:
            if self._syncing:
                return
            self.retargeter.q[j] = float(self.sliders[j].value)
            self._sliders_moved = True
            self.moved |= self.recording

    def _on_gizmo(self) -> None:
        with self._lock:
            self._hand_world = (np.array(self.gizmo.position, dtype=np.float64), np.array(self.gizmo.wxyz, dtype=np.float64))
            self._gizmo_moved = True
            self.moved |= self.recording

    def allowed(self) -> dict[str, bool]:
        """Which controls the current state allows; the page disables the others and :meth:`press` ignores them."""
        with self._lock:
            return {
                "start": not self.recording,
                "stop": self.recording and self.moved and self.store is not None,
                "discard": self.recording,
                "open": self.grip != 0.0,
                "close": self.grip != 1.0,
            }

    def _status_text(self) -> str:
        state = f"recording, frame {len(self._frames)}" if self.recording else "idle (press Start to record)"
        ik = {"vr": " · hand reached" if self.last_ok else " · **hand pose unreachable**",
              "leader": f" · tracking error {1000 * self.tracking_error:.1f} mrad"}.get(self.config.mode, "")
        note = f" · {self.status_note}" if self.status_note else ""
        return f"episode {self.episode_index} · {state} · saved {self.saved}{ik}{note}"

    def _show(self) -> None:
        self.scene.show(self.env.get_state())
        if self.config.mode == "leader" and getattr(self, "ghost", None) is not None:
            self._show_leader()
        self.status.content = self._status_text()
        self._update_buttons()

    def _show_leader(self) -> None:
        """The ghost at the leader's configuration, the sliders at its joints, now and then the follower's view."""
        env, q = self.env, self.retargeter.q
        self._ghost_data.qpos[:] = env.data.qpos
        self._ghost_data.qpos[env.arm_qadr] = q
        mujoco.mj_kinematics(env.model, self._ghost_data)
        self.ghost.show_data(self._ghost_data)
        self._syncing = True  # setting a slider's value calls its on_update: not a person's move
        try:
            for slider, value in zip(self.sliders, q):
                if abs(float(slider.value) - float(value)) > 5e-4:
                    slider.value = float(value)
        finally:
            self._syncing = False

    def _render_follower_view(self) -> None:
        """Leader mode, every few control steps: the follower's camera on the page. The renderer is made in the
        simulation thread and closed there (an OpenGL context belongs to the thread that made it)."""
        self._view_steps += 1
        if self._view_steps % FOLLOWER_VIEW_EVERY != 1:
            return
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.env.model, *FOLLOWER_VIEW[1:])
        self._renderer.update_scene(self.env.data, camera=FOLLOWER_VIEW[0])
        self.follower_view.image = self._renderer.render()

    # ------------------------------------------------------------------ controls (thread-safe)
    def _control(self, name: str) -> None:
        self.grip = 1.0 if name == "close" else 0.0  # the gripper buttons
        self.moved |= self.recording

    def set_hand(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Move the hand (the gizmo) to a pose in the robot base frame (m, wxyz)."""
        world = (self.env.to_world(np.asarray(pos, dtype=np.float64)), self.env.quat_to_world(np.asarray(quat, dtype=np.float64)))
        with self._lock:
            self._hand_world = world
            self.gizmo.position, self.gizmo.wxyz = world
            self._gizmo_moved = True
            self.moved |= self.recording

    def set_leader(self, q: np.ndarray) -> None:
        """Leader mode: put the leader arm at joint positions ``q`` (rad, arm_joints order), as its sliders do."""
        if self.config.mode != "leader":
            raise DemoError("--mode", f"set_leader moves the leader arm of --mode leader, not of {self.config.mode}")
        with self._lock:
            self.retargeter.q[:] = np.asarray(q, dtype=np.float64)
            self._sliders_moved = True
            self.moved |= self.recording

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured EE pose, base frame."""
        with self._lock:
            pos, quat = self.env.ee_pose()
            return pos.copy(), quat.copy()

    # ------------------------------------------------------------------ episodes
    def _reset_episode(self) -> None:
        env = self.env
        self.seed = episode_seed(self.config.seed, self.episode_index)
        env.reset(self.seed)
        self.grip = float(env.robot.home_gripper)
        self._frames, self._ok, self._err, self._first_success = [], [], [], None
        if self.retargeter is not None:
            self.retargeter.reset()
        self._hand_world = self._ee_world()
        if getattr(self, "gizmo", None) is not None:
            self.gizmo.position, self.gizmo.wxyz = self._hand_world
        self.moved = False

    def _finish(self, save: bool) -> None:
        if not self.recording and not self._frames:
            return
        self.recording = False
        if save and self._frames and self.store is not None:
            data = {k: np.stack([f[k] for f in self._frames]) for k in self._frames[0]}
            ok = np.array(self._ok, dtype=bool)[:, None]
            data["info.ik_ok"], data["info.ik_error"] = ok, np.array(self._err, dtype=np.float32)
            info = episode_info(self.human, InputEpisode(-1, self.seed, None), self.seed, self.env.success(),
                                self._first_success, ok)
            self.store.append_episode(data, **info)
            self.saved += 1
            self.status_note = f"saved episode ({len(self._frames)} frames, success {info['success']})"
        else:
            self.status_note = "discarded" if not save else "nothing saved (no --out)"
        self.episode_index += 1
        self._reset_episode()

    # ------------------------------------------------------------------ simulation
    def _ee_world(self) -> tuple[np.ndarray, np.ndarray]:
        pos, quat = self.env.ee_pose()
        return self.env.to_world(pos), self.env.quat_to_world(quat)

    def _soften_arm(self, factor: float) -> None:
        m, acts = self.env.model, self.env.arm_act
        # Position servo: force = kp (target - q) - kv qdot; bias = [0, -kp, -kv].
        m.actuator_gainprm[acts, 0] *= factor
        m.actuator_biasprm[acts, 1] *= factor
        m.actuator_biasprm[acts, 2] *= np.sqrt(factor)

    def step(self) -> None:
        """One control step: command from the hand, physics, recording, page update."""
        with self._lock:
            env = self.env
            frame = env.frame() if self.recording else None
            hand_pos, hand_quat = self._hand_base()
            if self.config.mode == "leader":
                # A leader arm stays where the person left it: the IK moves it only after its hand was dragged,
                # until it is there (a step of IK moves it at most its joint speed limits allow).
                if self._gizmo_moved:
                    r = self.retargeter(hand_pos, hand_quat)
                    self._gizmo_moved = not (r.pos_err < LEADER_AT_HAND_M and r.rot_err < LEADER_AT_HAND_RAD)
                else:
                    r = self.retargeter.hold()
                if self._sliders_moved:  # the sliders moved the leader: its hand (the gizmo) follows it
                    self._sliders_moved = False
                    self._set_gizmo_to_leader()
                command = np.r_[r.q, self.grip].astype(np.float32)
                env.step(command)  # the follower's servos track the leader
                self.tracking_error = float(np.max(np.abs(env.data.qpos[env.arm_qadr] - r.q)))
                label, ok, err = command, r.ok, (r.pos_err, r.rot_err)
                self.last_ok = r.ok
            elif self.config.mode == "vr":
                r = self.retargeter(hand_pos, hand_quat)
                command = np.r_[r.q, self.grip].astype(np.float32)
                env.step(command)
                label, ok, err = command, r.ok, (r.pos_err, r.rot_err)
                self.last_ok = r.ok
            else:
                self._drag_step()
                label = np.r_[env.data.qpos[env.arm_qadr], self.grip].astype(np.float32)
                ok, err = True, (0.0, 0.0)
            if frame is not None:
                frame["action"] = label
                frame["info.executed_action"] = label
                frame["info.ee_target"] = np.r_[hand_pos, hand_quat].astype(np.float32)
                self._frames.append(frame)
                self._ok.append(ok)
                self._err.append(err)
                if self._first_success is None and env.success():
                    self._first_success = len(self._frames)
                if len(self._frames) >= int(self.config.max_episode_s * env.fps):
                    self.status_note = "reached the episode length limit"
                    self._finish(save=True)
            self._show()
            if self.config.mode == "leader":
                self._render_follower_view()

    def _set_gizmo_to_leader(self) -> None:
        pos, quat = self.retargeter.ee_pose()
        self._hand_world = (self.env.to_world(pos), self.env.quat_to_world(quat))
        self.gizmo.position, self.gizmo.wxyz = self._hand_world

    def _hand_base(self) -> tuple[np.ndarray, np.ndarray]:
        pos_w, quat_w = self._hand_world
        base = self.env.base
        return base.rot.T @ (pos_w - base.pos), quat_mul(quat_conj(base.quat), quat_w)

    def _drag_step(self) -> None:
        """Physics of one control step with the arm backdriven by a spring from the gizmo."""
        env, cfg = self.env, self.config
        m, d = env.model, env.data
        target_p, target_q = self._hand_world
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        dofs = env.arm_dadr
        n_sub, env.n_substeps = env.n_substeps, 1
        try:
            for _ in range(n_sub):
                mujoco.mj_jacSite(m, d, jacp, jacr, env.ee_site)
                v = jacp @ d.qvel
                w = jacr @ d.qvel
                force = cfg.spring_stiffness * (target_p - d.site_xpos[env.ee_site]) - cfg.spring_damping * v
                current = np.empty(4)
                mujoco.mju_mat2Quat(current, d.site_xmat[env.ee_site])
                err = quat_mul(target_q, quat_conj(current))
                if err[0] < 0:
                    err = -err
                rotvec = np.zeros(3)
                mujoco.mju_quat2Vel(rotvec, err, 1.0)
                torque = cfg.spring_rot_stiffness * rotvec - cfg.spring_rot_damping * w
                d.qfrc_applied[:] = 0.0
                d.qfrc_applied[dofs] = jacp[:, dofs].T @ force + jacr[:, dofs].T @ torque
                env.step(np.r_[d.qpos[env.arm_qadr], self.grip])
        finally:
            env.n_substeps = n_sub
            d.qfrc_applied[:] = 0.0


def realtime_loop(session: Any, fps: float, stop: threading.Event) -> None:
    """``session.step()`` at ``fps`` in real time until ``stop`` is set. An error in a step keeps the page alive and
    says what went wrong (``session.status_note``, shown by ``session.status`` from ``session._status_text()``)."""
    dt = 1.0 / fps
    next_t = time.perf_counter()
    while not stop.is_set():
        try:
            session.step()
        except Exception as exc:  # keep the page alive; say what went wrong
            session.status_note = f"error: {type(exc).__name__}: {exc}"
            with contextlib.suppress(Exception):
                session.status.content = session._status_text()
        next_t += dt
        delay = next_t - time.perf_counter()
        if delay < -0.5:
            next_t = time.perf_counter()  # fell behind (slow machine): do not race to catch up
        stop.wait(max(0.0, delay))


def _quiet(enabled: bool) -> Any:
    return contextlib.redirect_stdout(io.StringIO()) if enabled else contextlib.nullcontext()


def serve_teleop(config: TeleopConfig) -> TeleopSession:
    """Start a session; returns once the page is served (``session.url``)."""
    return TeleopSession(config)
