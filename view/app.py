"""`demo view`: replay a store's episodes in the browser (viser), from the recorded simulator states.

The page holds: the 3D scene (the store's robot and task scene, posed frame by frame from
``sim.state``), an episode picker whose entries carry each episode's curation flags (success,
masks), a details panel and a table of neighbouring episodes with their ``mask.*``/``score.*``
columns, a timeline slider with play/pause and speed, the current camera image when the store has
``obs.image_*`` keys, and uPlot curves of the current episode's action and of one chosen
observation (or ``info.*``) key.

The scene model comes from the store's metadata: ``meta.task["name"]`` and ``["options"]`` and
the robot ``meta.robot`` records (``demo.sim.robot_record.resolve_robot``: the files the store
carries, or ``robot=``/``--robot``) go to ``demo.sim.make_env``; ``mjcf=`` (``--mjcf``) overrides
it with any MJCF file. Without a model, or when ``sim.state`` does not fit it, the page still shows
curves and flags and says why there is no 3D scene (a missing robot file is named there).

Library use (tests, notebooks)::

    viewer = serve("pick.zarr", port=0)   # returns once the server listens; viewer.url
    viewer.set_episode(3); viewer.set_frame(10)
    viewer.stop()
"""

from __future__ import annotations

import contextlib
import io
import threading
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError, first_line
from demo.sim import TASK_NAMES, make_env
from demo.sim.robot_record import resolve_robot
from demo.store import EpisodeStore, StoreMeta
from demo.store.spec import is_image
from demo.view.flags import EpisodeFlags
from demo.view.scene import MujocoScene, state_mismatch

PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf")
MAX_CURVE_DIMS = 32
SPEEDS = ("0.25x", "0.5x", "1x", "2x", "4x")
X_NOT_TIME = {"x": {"time": False}}  # uPlot reads x as UNIX time unless told otherwise


def load_scene_model(
    meta: StoreMeta, mjcf: str | Path | None = None, robot: str | Path | None = None, where: str | Path | None = None
) -> tuple[Any, Any, str]:
    """``(model, owner, description)`` for the store's scene; ``model`` is None with the reason.

    ``owner`` is what must be closed when done (a ``demo.sim`` env) or None. ``robot``: a robot
    config overriding the store's (a bad one raises DemoError); ``where``: the store directory.
    """
    if mjcf is not None:
        path = Path(mjcf)
        try:
            return mujoco.MjModel.from_xml_path(str(path)), None, f"MJCF {path}"
        except (ValueError, OSError) as exc:
            raise DemoError(path, f"cannot load MJCF ({first_line(exc)})") from None
    task = meta.task or {}
    name = task.get("name")
    if not name:
        return None, None, "the store's metadata names no task (pass --mjcf to draw a scene)"
    options = task.get("options") if isinstance(task.get("options"), dict) else {}
    if name not in TASK_NAMES:
        return None, None, f"cannot build task {name!r}: not a demo.sim task (pass --mjcf to draw a scene)"
    if robot is not None:
        robot_config = resolve_robot(meta.robot, robot)  # the user's own --robot: its errors are errors
    else:
        try:
            robot_config = resolve_robot(meta.robot, where=where)
        except DemoError as exc:
            return None, None, f"cannot find the store's robot: {exc}"
    try:
        env = make_env(str(name), robot=robot_config, **options)
    except DemoError as exc:
        return None, None, f"cannot build task {name!r}: {exc}"
    except Exception as exc:  # an unknown task or options: still show curves and flags
        return None, None, f"cannot build task {name!r} ({type(exc).__name__}: {first_line(exc)})"
    return env.model, env, f"task {name} ({robot_config.name})"


class Viewer:
    """A running viewer; build it with :func:`serve`. Thread-safe setters for tests."""

    def __init__(
        self,
        store_path: str | Path,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        episode: int = 0,
        mjcf: str | Path | None = None,
        robot: str | Path | None = None,
        autoplay: bool = True,
        verbose: bool = False,
    ):
        import viser  # deferred: heavy dependency (viser)

        self.store = EpisodeStore.open(store_path)
        if self.store.num_episodes == 0:
            raise DemoError(store_path, "has no episodes to view")
        if not 0 <= episode < self.store.num_episodes:
            raise DemoError(store_path, f"has no episode {episode} (it has {self.store.num_episodes})")
        meta = self.store.meta
        self.fps = float(meta.fps)
        self.flags = EpisodeFlags(self.store)
        self.images = [k for k, s in meta.features.items() if k.startswith("obs.") and is_image(s)]
        self.curve_keys = [
            k for k, s in meta.features.items()
            if k.startswith(("obs.", "info.")) and not is_image(s) and np.dtype(s.dtype).kind in "fiub"
            and int(np.prod(s.shape, dtype=np.int64)) <= MAX_CURVE_DIMS
        ]
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self.playing = False
        self.episode = -1
        self.frame = 0
        self.data: dict[str, np.ndarray] = {}
        self.scene = None
        self.scene_note = ""

        model, self._owner, description = (None, None, "")
        if "sim.state" not in meta.features:
            self.scene_note = "the store has no sim.state: nothing to replay in 3D"
        else:
            model, self._owner, description = load_scene_model(meta, mjcf, robot, store_path)
            if model is None:
                self.scene_note = description
        self.verbose = verbose
        with _quiet(not verbose):  # viser prints its own banner; the CLI prints the URL itself
            self.server = viser.ViserServer(host=host, port=port, label=f"demo view: {Path(store_path).name}",
                                            verbose=verbose)
        self._host, self._port = self.server.get_host(), self.server.get_port()
        try:
            self._build_gui(Path(store_path), description)
            if model is not None:
                self._build_scene(model)
            self.set_episode(episode)
            if autoplay:
                self.play()
        except BaseException:
            self.stop()
            raise
        self._thread = threading.Thread(target=self._play_loop, name="demo-view-player", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ building
    def _build_scene(self, model: Any) -> None:
        first = np.asarray(self.store.read_episode(0, ["sim.state"])["sim.state"][0])
        problem = state_mismatch(model, first)
        if problem:
            self.scene_note = problem
            self.note.content = f"⚠ {problem}"
            return
        self.server.scene.set_up_direction("+z")
        # A hemisphere light instead of viser's HDRI environment map: the map's prefiltering takes tens
        # of seconds in software WebGL (headless browsers, machines without a GPU); looks about the same.
        self.server.scene.configure_environment_map(None)
        self.server.scene.add_light_hemisphere("/lights/sky", sky_color=(255, 255, 255), ground_color=(90, 90, 100),
                                               intensity=2.0)
        scene = MujocoScene(self.server.scene, model)
        self.scene = scene
        position, look_at = scene.camera_pose()
        self.server.initial_camera.position = tuple(position)
        self.server.initial_camera.look_at = tuple(look_at)
        if scene.skipped:
            self.scene_note = "not drawn: " + "; ".join(scene.skipped)
            self.note.content = f"⚠ {self.scene_note}"

    def _build_gui(self, path: Path, description: str) -> None:
        gui = self.server.gui
        meta = self.store.meta
        summary = (f"**{path.name}**: {self.store.num_episodes} episodes, {self.store.num_frames} frames at "
                   f"{self.fps:g} Hz; task `{(meta.task or {}).get('name', '-')}`, robot `{(meta.robot or {}).get('name', '-')}`, "
                   f"action `{meta.action.name}`")
        gui.add_markdown(summary)
        self.note = gui.add_markdown("")
        with gui.add_folder("Episode"):
            self.picker = gui.add_dropdown("episode", self.flags.labels(), initial_value=self.flags.label(0))
            self.details = gui.add_markdown("")
        with gui.add_folder("Timeline"):
            self.slider = gui.add_slider("frame", min=0, max=1, step=1, initial_value=0)
            self.time_text = gui.add_markdown("")
            self.play_button = gui.add_button("play")
            self.speed = gui.add_dropdown("speed", SPEEDS, initial_value="1x")
            self.loop = gui.add_checkbox("loop", initial_value=True)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Curves"):
            self.action_plot = gui.add_uplot(
                (np.zeros(2), np.zeros(2)), ({"label": "frame"}, {"label": "a"}), title=f"action ({meta.action.name})",
                aspect=1.6, scales=X_NOT_TIME,
            )
            self.curve_key = None
            self.obs_plot = None
            if self.curve_keys:
                self.curve_key = gui.add_dropdown("observation", self.curve_keys, initial_value=self.curve_keys[0])
                self.obs_plot = gui.add_uplot((np.zeros(2), np.zeros(2)), ({"label": "frame"}, {"label": "x"}),
                                              title=self.curve_keys[0], aspect=1.6, scales=X_NOT_TIME)
        self.camera_image = None
        if self.images:
            with tabs.add_tab("Camera"):
                self.camera_key = gui.add_dropdown("camera", self.images, initial_value=self.images[0])
                spec = meta.features[self.images[0]]
                self.camera_image = gui.add_image(np.zeros(spec.shape[:2] + (3,), np.uint8), label=self.images[0])
        with tabs.add_tab("Episodes"):
            self.flag_table = gui.add_markdown("")

        self.picker.on_update(lambda _: self.set_episode(int(self.picker.value.split(":", 1)[0])))
        self.slider.on_update(lambda _: self._show(int(self.slider.value)))
        self.play_button.on_click(lambda _: self.pause() if self.playing else self.play())
        if self.curve_key is not None:
            self.curve_key.on_update(lambda _: self._update_obs_plot())
        if self.images:
            self.camera_key.on_update(lambda _: self._show(self.frame))
        self.note.content = f"3D scene: {description}" if not self.scene_note else f"⚠ {self.scene_note}"

    # ------------------------------------------------------------------ state changes
    def set_episode(self, index: int) -> None:
        """Show episode ``index`` from its first frame."""
        if not 0 <= index < self.store.num_episodes:
            raise DemoError(self.store.path, f"has no episode {index} (it has {self.store.num_episodes})")
        with self._lock:
            if index == self.episode:
                return
            keys = ["action", *self.curve_keys, *self.images]
            if self.scene is not None:
                keys.append("sim.state")
            self.data = self.store.read_episode(index, keys)
            self.episode = index
            self.length = len(self.data["action"])
            label = self.flags.label(index)
            if self.picker.value != label:
                self.picker.value = label
            self.details.content = self.flags.details(index)
            self.flag_table.content = self.flags.table(index)
            self._update_action_plot()
            self._update_obs_plot()
            self.slider.max = max(1, self.length - 1)
            self.frame = -1
            if self.slider.value != 0:
                self.slider.value = 0  # calls _show(0)
            else:
                self._show(0)

    def set_frame(self, t: int) -> None:
        """Show frame ``t`` of the current episode (clipped to the episode)."""
        with self._lock:
            t = int(np.clip(t, 0, self.length - 1))
            if self.slider.value != t:
                self.slider.value = t
            else:
                self._show(t)

    def _show(self, t: int) -> None:
        with self._lock:
            t = int(np.clip(t, 0, self.length - 1))
            self.frame = t
            with self.server.atomic():
                if self.scene is not None:
                    self.scene.show(self.data["sim.state"][t])
                if self.camera_image is not None:
                    key = self.camera_key.value
                    image = self.data[key][t]
                    self.camera_image.image = np.repeat(image, 3, axis=2) if image.shape[2] == 1 else image[:, :, :3]
                self.time_text.content = f"frame {t} / {self.length - 1} · {t / self.fps:.2f} s"

    def _series(self, values: np.ndarray, names: tuple[str, ...] | None) -> tuple[tuple[np.ndarray, ...], tuple[dict, ...]]:
        flat = values.reshape(len(values), -1).astype(np.float64)
        x = np.arange(len(values), dtype=np.float64)
        labels = list(names) if names is not None and len(names) == flat.shape[1] else [str(i) for i in range(flat.shape[1])]
        series = ({"label": "frame"}, *({"label": labels[i], "stroke": PALETTE[i % len(PALETTE)], "width": 1.5}
                                        for i in range(flat.shape[1])))
        return (x, *(flat[:, i] for i in range(flat.shape[1]))), series

    def _update_action_plot(self) -> None:
        data, series = self._series(self.data["action"], self.store.meta.action.names)
        self.action_plot.series = series
        self.action_plot.data = data

    def _update_obs_plot(self) -> None:
        if self.obs_plot is None or self.curve_key is None:
            return
        with self._lock:
            key = self.curve_key.value
            data, series = self._series(self.data[key], self.store.meta.features[key].names)
            self.obs_plot.title = key
            self.obs_plot.series = series
            self.obs_plot.data = data

    # ------------------------------------------------------------------ playback and shutdown
    def play(self) -> None:
        self.playing = True
        self.play_button.label = "pause"

    def pause(self) -> None:
        self.playing = False
        self.play_button.label = "play"

    def _play_loop(self) -> None:
        while not self._stop.is_set():
            if not self.playing:
                self._stop.wait(0.05)
                continue
            speed = float(self.speed.value.rstrip("x"))
            with self._lock:
                t = self.frame + 1
                if t >= self.length:
                    if not self.loop.value:
                        self.pause()
                        continue
                    t = 0
                self.set_frame(t)
            self._stop.wait(1.0 / (self.fps * speed))

    @property
    def host(self) -> str:
        return self._host

    @property
    def port(self) -> int:
        return self._port

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def stop(self) -> None:
        """Stop playback and the server, and release the scene model. Safe to call twice."""
        self._stop.set()
        thread = getattr(self, "_thread", None)
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
        server = getattr(self, "server", None)
        if server is not None:
            with _quiet(not getattr(self, "verbose", False)):
                server.stop()
            self.server = None  # type: ignore[assignment]
        owner = getattr(self, "_owner", None)
        if owner is not None and hasattr(owner, "close"):
            owner.close()
            self._owner = None
        self.store.close()


def serve(
    store_path: str | Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    *,
    episode: int = 0,
    mjcf: str | Path | None = None,
    robot: str | Path | None = None,
    autoplay: bool = True,
    verbose: bool = False,
) -> Viewer:
    """Start the viewer for the store at ``store_path``; returns once the server listens (viser waits).

    ``port=0`` picks a free port (``viewer.port``). Call ``viewer.stop()`` to shut it down.
    ``robot``: a robot config TOML to draw instead of the one the store records (``--robot``).
    """
    return Viewer(store_path, host=host, port=port, episode=episode, mjcf=mjcf, robot=robot, autoplay=autoplay,
                  verbose=verbose)


def _quiet(enabled: bool) -> Any:
    """Silence stdout (viser's banner and "Server stopped" lines) when ``enabled``."""
    return contextlib.redirect_stdout(io.StringIO()) if enabled else contextlib.nullcontext()
