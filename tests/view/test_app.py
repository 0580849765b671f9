"""`demo view`: the server replays recorded states, serves a page that renders in headless Chromium,
and stops cleanly on Ctrl-C."""

from __future__ import annotations

import base64
import io
import json
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.view.app import serve
from demo.view.scene import STATE_SPEC

XML = """
<mujoco>
  <worldbody>
    <light pos="0 0 2"/>
    <geom name="floor" type="plane" size="1 1 0.1" rgba="0.8 0.8 0.8 1"/>
    <body name="arm" pos="0 0 0.3">
      <joint name="hinge" type="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" rgba="0.1 0.3 0.95 1"/>
      <geom type="cylinder" pos="0.3 0 0" size="0.04 0.05" rgba="0.95 0.4 0.1 1"/>
    </body>
    <body name="cube" pos="0.4 0 0.05">
      <freejoint/>
      <geom type="box" size="0.05 0.05 0.05" rgba="0.95 0.1 0.1 1"/>
    </body>
  </worldbody>
</mujoco>
"""


def make_store(root: Path, state_size: int | None = None) -> tuple[Path, Path]:
    """A 3-episode store whose sim.state poses XML (hinge swings, cube rises), with a camera and flags."""
    xml = root / "scene.xml"
    xml.write_text(XML)
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    n = state_size or mujoco.mj_stateSize(model, STATE_SPEC)
    meta = StoreMeta(
        fps=20.0,
        features={"obs.hinge": FeatureSpec((1,), "float32", names=("hinge",)),
                  "obs.cube_pos": FeatureSpec((3,), "float32"),
                  "obs.image_front": FeatureSpec((16, 16, 3), "uint8"),
                  "sim.state": FeatureSpec((n,), "float64")},
        action=ActionSpec("joint_pos", ("hinge",), ("rad",)), robot={"name": "toy"}, task={"name": "toy"},
    )
    path = root / "v.zarr"
    with EpisodeStore.create(path, meta) as store:
        for e in range(3):
            length = 30 + 10 * e
            states, cube = [], []
            for t in range(length):
                data.qpos[0] = np.sin(t / 10 + e)
                data.qpos[1:4] = [0.4, 0.1 * np.cos(t / 7), 0.05 + 0.01 * t]
                s = np.zeros(mujoco.mj_stateSize(model, STATE_SPEC))
                mujoco.mj_getState(model, data, s, STATE_SPEC)
                states.append(s[:n] if state_size else s)
                cube.append(data.qpos[1:4].copy())
            hinge = np.sin(np.arange(length) / 10 + e)[:, None].astype(np.float32)
            store.append_episode({"action": hinge, "obs.hinge": hinge, "obs.cube_pos": np.array(cube, np.float32),
                                  "obs.image_front": np.full((length, 16, 16, 3), 40 * e, np.uint8),
                                  "sim.state": np.array(states)}, success=e != 1, seed=e)
        store.set_mask("train", [True, False, True])
        store.set_column("score.jerk", [0.1, 2.0, 0.3])
    return path, xml


@pytest.fixture(scope="module")
def toy(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return make_store(tmp_path_factory.mktemp("view"))


def wait_for(condition, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return False


def test_serve_replays_recorded_states(toy: tuple[Path, Path]) -> None:
    path, xml = toy
    viewer = serve(path, port=0, mjcf=xml, autoplay=False)
    try:
        assert viewer.host == "127.0.0.1" and viewer.scene is not None
        page = urllib.request.urlopen(viewer.url, timeout=5).read().decode()
        assert "<html" in page.lower()
        viewer.set_episode(2)
        viewer.set_frame(25)
        store = EpisodeStore.open(path)
        episode = store.read_episode(2)
        model = mujoco.MjModel.from_xml_path(str(xml))
        data = mujoco.MjData(model)
        mujoco.mj_setState(model, data, episode["sim.state"][25], STATE_SPEC)
        mujoco.mj_forward(model, data)
        cube = model.body("cube").id
        np.testing.assert_allclose(viewer.scene.bodies[cube].position, data.xpos[cube])
        np.testing.assert_allclose(viewer.scene.bodies[cube].position, episode["obs.cube_pos"][25], atol=1e-6)
        assert viewer.slider.value == 25 and viewer.slider.max == 49
        assert viewer.picker.value == "2: ok 50f [train]"
        assert "Episode 2" in viewer.details.content and "jerk = 0.3" in viewer.details.content
        np.testing.assert_array_equal(viewer.action_plot.data[1], episode["action"][:, 0])
        np.testing.assert_array_equal(viewer.obs_plot.data[1], episode["obs.hinge"][:, 0])
        assert np.all(viewer.camera_image.image == 80)
        viewer.picker.value = "1: FAIL 40f"  # what a click in the episode picker does
        assert viewer.episode == 1 and viewer.frame == 0 and viewer.slider.max == 39
        viewer.play()
        assert wait_for(lambda: viewer.frame >= 3)
        viewer.pause()
        frame = viewer.frame
        time.sleep(0.2)
        assert viewer.frame == frame
        with pytest.raises(DemoError, match="no episode 7"):
            viewer.set_episode(7)
    finally:
        viewer.stop()
    with pytest.raises(OSError):
        socket.create_connection((viewer.host, viewer.port), timeout=1).close()


def test_scene_problems_are_reported_not_fatal(tmp_path: Path, toy: tuple[Path, Path]) -> None:
    path, xml = make_store(tmp_path, state_size=5)
    viewer = serve(path, port=0, mjcf=xml, autoplay=False)
    try:
        assert viewer.scene is None and "mjSTATE_INTEGRATION" in viewer.scene_note
        viewer.set_frame(3)
        assert viewer.frame == 3  # curves and flags still work
    finally:
        viewer.stop()
    viewer = serve(toy[0], port=0, autoplay=False)  # task "toy" is not a demo.sim task
    try:
        assert viewer.scene is None and "toy" in viewer.scene_note
    finally:
        viewer.stop()
    with pytest.raises(DemoError, match="no episode 5"):
        serve(toy[0], port=0, episode=5)
    with pytest.raises(DemoError, match="no such store"):
        serve(tmp_path / "missing.zarr", port=0)


def test_scene_from_the_store_metadata(tmp_path: Path) -> None:
    sim = pytest.importorskip("demo.sim")
    env = sim.make_env("reach")
    frames = []
    for seed in range(5):  # five initial states stand in for an episode
        env.reset(seed=seed)
        frames.append(env.frame())
    meta = StoreMeta(fps=env.fps, features=dict(env.features), action=env.action_spec,
                     robot={"name": env.robot.name, "config": "builtin"}, task={"name": "reach", "options": {}})
    with EpisodeStore.create(tmp_path / "r.zarr", meta) as store:
        data = {k: np.stack([f[k] for f in frames]) for k in frames[0]}
        data["action"] = np.zeros((5, env.action_spec.dim), np.float32)
        store.append_episode(data, success=False, seed=0)
    env.close()
    viewer = serve(tmp_path / "r.zarr", port=0, autoplay=False)
    try:
        assert viewer.scene is not None, viewer.scene_note
        assert "reach" in viewer.note.content and len(viewer.scene.geoms) > 5
    finally:
        viewer.stop()


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


def chromium_screenshot(
    browser: str, url: str, wait_text: list[str], ready: Callable[[bytes], bool], timeout: float = 90.0
) -> tuple[bytes, str]:
    """Load ``url`` in headless Chromium (software WebGL) over the DevTools protocol.

    Waits until the page text holds every ``wait_text`` and then until a screenshot satisfies
    ``ready`` (scene nodes fade in), or the timeout; returns the last PNG and the page text.
    """
    from websockets.sync.client import connect

    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.Popen(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--window-size=1024,640", "--hide-scrollbars", "--no-first-run",
             "--remote-debugging-port=0", "--remote-allow-origins=*", f"--user-data-dir={profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + timeout
            port_file = Path(profile) / "DevToolsActivePort"
            while not (port_file.exists() and port_file.read_text().strip()):
                assert time.monotonic() < deadline, "chromium did not start"
                time.sleep(0.1)
            port = int(port_file.read_text().split()[0])
            targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read())
            with connect(next(t["webSocketDebuggerUrl"] for t in targets if t["type"] == "page"), max_size=None) as ws:
                ids = iter(range(1, 10**6))

                def call(method: str, **params: object) -> dict:
                    i = next(ids)
                    ws.send(json.dumps({"id": i, "method": method, "params": params}))
                    while True:
                        msg = json.loads(ws.recv(timeout=max(1.0, deadline - time.monotonic())))
                        if msg.get("id") == i:
                            return msg.get("result", {})

                call("Page.navigate", url=url)
                text = ""
                while not all(w in text for w in wait_text):
                    assert time.monotonic() < deadline, f"page never showed {wait_text}: {text[:300]!r}"
                    time.sleep(0.3)
                    result = call("Runtime.evaluate", expression="document.body ? document.body.innerText : ''")
                    text = result.get("result", {}).get("value", "")
                while True:
                    png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
                    if ready(png) or time.monotonic() > deadline:
                        return png, text
                    time.sleep(0.5)
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


@pytest.mark.skipif(find_chromium() is None, reason="no chromium: `apt-get install -y chromium` to run the browser check")
def test_page_renders_in_headless_chromium(toy: tuple[Path, Path]) -> None:
    from PIL import Image

    def coloured_pixels(png: bytes) -> int:
        """Strongly coloured pixels in the 3D viewport (left of the GUI panel, below the WebGL notice):
        the blue, orange and red geoms; the floor and background are grey/white."""
        image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)
        image = image[150:, 320:image.shape[1] - 340]
        return int(((image.max(axis=2) - image.min(axis=2)) > 100).sum())

    path, xml = toy
    viewer = serve(path, port=0, mjcf=xml, autoplay=False)
    try:
        viewer.set_frame(10)
        png, text = chromium_screenshot(find_chromium(), viewer.url, ["Episode", "Timeline", "frame 10 / 29"],
                                        ready=lambda png: coloured_pixels(png) > 300)
    finally:
        viewer.stop()
    assert "demo view: v.zarr" in text and "Episode 0 of 3" in text and "masks: train ✔" in text
    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)
    assert image.std() > 10, "blank screenshot"
    assert coloured_pixels(png) > 300, "the 3D scene shows no geoms"


@pytest.mark.slow
def test_cli_stops_cleanly_on_ctrl_c(toy: tuple[Path, Path]) -> None:
    path, xml = toy
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from demo.cli.main import main; sys.exit(main())",
         "view", str(path), "--port", "0", "--mjcf", str(xml), "--episode", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    try:
        assert wait_for(lambda: any("http://127.0.0.1:" in line for line in lines), timeout=30), lines
        url = next(line for line in lines if "http://" in line).split()[2]
        assert urllib.request.urlopen(url, timeout=5).status == 200
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    reader.join(5)
    stderr = proc.stderr.read()
    assert rc == 0, stderr
    assert "Traceback" not in stderr
    assert any("stopped" in line for line in lines)


def test_cli_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "notastore").mkdir()
    assert main(["view", str(tmp_path / "notastore")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "not a demo episode store" in err and err.strip().count("\n") == 0
