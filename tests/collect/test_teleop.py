"""`demo teleop`: the live page serves on 127.0.0.1, a scripted websocket client (viser's own wire
format) drives the gizmo and the buttons, the robot's EE follows to within 5 mm, and headless
Chromium renders the page (screenshot not blank)."""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
import viser
import zstandard
from websockets.sync.client import connect

from demo.view.teleop import TeleopConfig, TeleopSession
from demo.store import EpisodeStore
from viser import _messages as vm

CHROMIUM = next((p for p in (shutil.which("chromium"), shutil.which("chromium-browser"), "/usr/bin/chromium")
                 if p and os.path.exists(p)), None)


class ViserWireClient:
    """A minimal viser client: subprotocol viser-v<version>, msgpack out, zstd+msgpack windows in."""

    def __init__(self, port: int):
        self.ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None,
                          open_timeout=20, close_timeout=1)
        self.messages: list[dict[str, Any]] = []

    def send(self, message: Any) -> None:
        self.ws.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                raw = self.ws.recv(timeout=0.1)
            except TimeoutError:
                continue
            n_inner = int.from_bytes(raw[0:8], "little")
            n_comp = int.from_bytes(raw[8:16], "little")
            inner = zstandard.ZstdDecompressor().decompress(raw[16:16 + n_comp], max_output_size=n_inner)
            self.messages += msgspec.msgpack.decode(inner)["messages"]

    def find(self, kind: str, **match: Any) -> dict[str, Any]:
        """The first message of ``kind`` matching ``match``, pumping for up to 30 s until it arrives (a loaded
        machine sends the GUI late)."""
        end = time.monotonic() + 30.0
        while True:
            for m in self.messages:
                if m["type"] == kind and all(_get(m, k) == v for k, v in match.items()):
                    return m
            if time.monotonic() > end:
                raise AssertionError(f"no {kind} {match} among {len(self.messages)} messages")
            self.pump(0.5)

    def camera(self) -> None:
        self.send(vm.ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0), position=(1.5, -1.0, 1.0), fov=1.0, near=0.01, far=100.0,
            image_height=480, image_width=640, look_at=(0.4, 0.0, 0.1), up_direction=(0.0, 0.0, 1.0)))

    def click(self, label: str) -> None:
        button = self.find("GuiButtonMessage", **{"props.label": label})
        self.send(vm.GuiUpdateMessage(uuid=button["uuid"], updates={"value": True}))

    def close(self) -> None:
        self.ws.close()


@contextlib.contextmanager
def connected(config: TeleopConfig) -> Iterator[tuple[TeleopSession, ViserWireClient]]:
    """A live session and a websocket client to it that has sent its first camera message (viser ignores a
    client's input until then); both closed after."""
    session = TeleopSession(config)
    client = None
    try:
        client = ViserWireClient(session.port)
        client.camera()
        client.pump(1.5)
        yield session, client
    finally:
        if client is not None:
            client.close()
        session.close()


def save(session: TeleopSession, client: ViserWireClient) -> None:
    """Click Stop & save, and wait for the episode to be stored."""
    client.click("Stop & save")
    assert _wait_until(lambda: session.saved == 1, 30.0)


def _get(message: dict[str, Any], dotted: str) -> Any:
    value: Any = message
    for part in dotted.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return value


def _wait_until(predicate, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.1)
    return predicate()


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["vr", "kinesthetic", "leader"])
def test_websocket_client_moves_the_ee_to_the_gizmo_and_records(tmp_path: Path, mode: str) -> None:
    out = tmp_path / "teleop.zarr"
    with connected(TeleopConfig(mode=mode, task="pick", out=str(out), port=0, operator="ws-client")) as (session, client):
        assert session.url.startswith("http://127.0.0.1:")
        gizmo = client.find("TransformControlsMessage")
        client.click("Start")
        assert _wait_until(lambda: session.recording, 5.0)
        pos, quat = session.ee_pose()
        target = pos + np.array([0.04, -0.05, -0.06])
        world = session.env.to_world(target)
        client.send(vm.TransformControlsUpdateMessage(
            name=gizmo["name"], wxyz=tuple(session.env.quat_to_world(quat)), position=tuple(world)))
        client.click("Close gripper")
        reached = _wait_until(lambda: np.linalg.norm(session.ee_pose()[0] - target) < 0.005, 20.0)
        error = np.linalg.norm(session.ee_pose()[0] - target)
        assert reached, f"EE is {error * 1000:.1f} mm from the gizmo"
        save(session, client)
    store = EpisodeStore.open(out)
    row = store.episode_info(0)
    assert (row["source"], row["operator"], row["task"]) == (mode, "ws-client", "pick")
    ep = store.read_episode(0)
    # The recording holds the EE at the gizmo (under load the frames after it may lag the live pose by a few mm)
    assert np.linalg.norm(ep["obs.ee_pos"] - target, axis=1).min() < 0.01
    assert ep["action"][-1, -1] == 1.0  # the gripper button reached the recorded command
    assert ep["info.ik_ok"].shape == (store.episode_lengths[0], 1)
    store.close()


def test_leader_sliders_move_the_follower_which_records_the_leaders_joints(tmp_path: Path, replays) -> None:
    """Leader mode by joint sliders (a websocket client sets one): the follower's servos track the leader, the
    recorded actions are the leader's joint positions, the tracking error shrinks once it arrives, the ghost and
    the follower's camera are on the page, and the episode replays from its first state."""
    out = tmp_path / "leader.zarr"
    with connected(TeleopConfig(mode="leader", task="pick", out=str(out), port=0)) as (session, client):
        client.find("GuiImageMessage")  # the follower's camera, rendered as the simulation runs
        assert _wait_until(lambda: np.asarray(session.follower_view.image).std() > 5, 10.0)
        assert any(m["type"].endswith("Message") and str(_get(m, "name") or "").startswith("/leader")
                   for m in client.messages)  # the leader arm's ghost
        client.click("Start")
        assert _wait_until(lambda: session.recording, 5.0)
        slider = client.find("GuiSliderMessage", **{"props.label": "joint1"})
        target = float(session.retargeter.q[0]) + 0.3
        client.send(vm.GuiUpdateMessage(uuid=slider["uuid"], updates={"value": target}))
        joint1 = session.env.arm_qadr[0]
        assert _wait_until(lambda: abs(session.env.data.qpos[joint1] - target) < 0.01, 20.0)
        assert _wait_until(lambda: session.tracking_error < 0.01, 10.0)
        save(session, client)
    with EpisodeStore.open(out) as store:
        assert store.episode_info(0)["source"] == "leader"
        ep = store.read_episode(0, ["action", "obs.joint_pos", "sim.state"])
    assert np.isclose(ep["action"][:, 0], target, atol=1e-3).any()  # the leader's joint, recorded as the action
    lag = ep["action"][:-1, 0] - ep["obs.joint_pos"][1:, 0]
    assert np.abs(lag).max() > 0.01  # the follower lagged its leader while it moved
    replays("pick", ep)

@pytest.mark.slow
def test_a_leader_session_driven_along_the_experts_targets_picks_the_cube(tmp_path: Path) -> None:
    """The leader moved (in real time, through the library API the sliders use) along the scripted expert's joint
    targets for the session's first episode: the follower picks the cube, and the saved episode says so."""
    from demo.collect.scripted import CollectConfig, make_env_for, scripted_episode

    config = CollectConfig(task="pick", episodes=1, seed=0)
    env = make_env_for(config)
    try:
        expert, _ = scripted_episode(env, config, 0)  # episode_seed(0, 0): the session's first episode
    finally:
        env.close()
    out = tmp_path / "leader.zarr"
    session = TeleopSession(TeleopConfig(mode="leader", task="pick", out=str(out), port=0))
    try:
        session.press("start")
        for action in expert["action"]:
            session.set_leader(action[:-1])
            session.press("close" if action[-1] > 0.5 else "open")
            time.sleep(1.0 / session.env.fps)
        time.sleep(1.0)  # the follower catches up and holds the cube
        session.press("stop")
        assert _wait_until(lambda: session.saved == 1, 5.0)
    finally:
        session.close()
    with EpisodeStore.open(out) as store:
        assert store.episode_info(0)["source"] == "leader" and bool(store.column("success")[0])


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (apt-get install -y chromium); CI installs it")
@pytest.mark.parametrize("mode", ["vr", "leader"])
def test_page_renders_in_headless_chromium(tmp_path: Path, mode: str) -> None:
    session = TeleopSession(TeleopConfig(mode=mode, task="pick", port=0))
    try:
        assert page_drawn(session.url, tmp_path / "teleop.png"), "the 3D view stayed blank"
    finally:
        session.close()


def page_drawn(url: str, png_path: Path) -> bool:
    """Whether headless Chromium draws the 3D scene of the page at ``url`` within 45 s (its last screenshot saved)."""
    from PIL import Image

    profile = tempfile.mkdtemp(prefix="chromium-", dir=png_path.parent)
    browser = subprocess.Popen(
        [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--window-size=900,650", "--remote-debugging-port=0",
         f"--user-data-dir={profile}", "about:blank"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        port_file = Path(profile) / "DevToolsActivePort"
        assert _wait_until(port_file.exists, 30.0), "chromium did not start"
        devtools = int(port_file.read_text().split()[0])
        pages = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{devtools}/json/list", timeout=10).read())
        page = next(p for p in pages if p["type"] == "page")
        with connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=20) as cdp:
            ids = iter(range(1, 10_000))

            def call(method: str, **params: Any) -> dict[str, Any]:
                i = next(ids)
                cdp.send(json.dumps({"id": i, "method": method, "params": params}))
                while True:
                    reply = json.loads(cdp.recv(timeout=60))
                    if reply.get("id") == i:
                        return reply.get("result", {})

            call("Page.navigate", url=url)
            image = None
            end = time.monotonic() + 45.0
            while time.monotonic() < end:
                time.sleep(2.0)
                png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
                image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float64)
                if _scene_drawn(image):
                    break
        assert image is not None
        png_path.write_bytes(png)
        return _scene_drawn(image)
    finally:
        browser.terminate()
        browser.wait(timeout=20)


def _scene_drawn(image: np.ndarray) -> bool:
    """The 3D view (lower left, away from the panel and notices) shows the scene, not a blank canvas."""
    h, w, _ = image.shape
    view = image[h // 2:, : w // 2]
    colours = len(np.unique(view.reshape(-1, 3).astype(np.uint8), axis=0))
    return bool(view.std() > 10.0 and colours > 50)


def test_bad_mode_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    from demo.cli.main import main

    assert main(["teleop", "--mode", "haptic"]) == 1
    err = capsys.readouterr().err
    assert "error: --mode: unknown mode 'haptic'" in err.replace("\n", " ")


def test_buttons_enable_only_what_the_state_allows(tmp_path: Path) -> None:
    out = tmp_path / "t.zarr"
    session = TeleopSession(TeleopConfig(mode="vr", task="reach", out=str(out), port=0), run_thread=False)
    try:
        def enabled() -> set[str]:
            assert {n for n, b in session.buttons.items() if not b.disabled} == {n for n, ok in session.allowed().items() if ok}
            return {n for n, ok in session.allowed().items() if ok}

        open_or_close = {"open", "close"} & enabled()
        assert {"start"} | open_or_close == enabled()  # nothing recorded: neither save nor discard
        session.press("stop")
        assert session.saved == 0 and "not now" in session.status_note
        session.press("start")
        for _ in range(3):
            session.step()
        assert enabled() >= {"discard"} and not enabled() & {"start", "stop"}  # recording, but no motion yet
        pos, quat = session.ee_pose()
        session.set_hand(pos + np.array([0.02, 0.0, 0.0]), quat)
        session.step()
        assert "stop" in enabled()
        session.press("discard")
        assert session.saved == 0 and not session.recording and not enabled() & {"stop", "discard"}
        session.press("start")
        session.press("close")
        session.step()
        assert "close" not in enabled() and {"open", "stop", "discard"} <= enabled()
        session.press("close")  # already closed: ignored
        assert "not now" in session.status_note
        session.press("stop")
        assert session.saved == 1 and "start" in enabled()
    finally:
        session.close()
    with EpisodeStore.open(out) as store:
        assert store.num_episodes == 1 and store.episode_lengths[0] == 1


def test_stopped_before_any_episode_leaves_no_store(tmp_path: Path) -> None:
    """A collection is invisible before its first episode: before, an empty store was left at --out."""
    out = tmp_path / "t.zarr"
    TeleopSession(TeleopConfig(mode="vr", task="reach", out=str(out), port=0), run_thread=False).close()
    assert not out.exists() and [p for p in tmp_path.iterdir() if not p.name.endswith(".lock")] == []
