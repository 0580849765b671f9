"""`demo teleop --mode leader --env demo.sim.aloha_scene:TASK --robot aloha_vx300s.toml`: both leader arms live in the
browser (a websocket client moves their sliders), the followers tracking them, episodes that succeed and replay."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from viser import _messages as vm

from demo.cli.main import main
from demo.collect.foreign import foreign_episode
from demo.seeds import episode_seed
from demo.sim import make_env
from demo.store import EpisodeStore
from demo.view.teleop_arms import ArmsLeaderConfig, ArmsLeaderSession
from tests.collect.test_leader_arms import assert_replays
from tests.collect.test_teleop import ViserWireClient, _wait_until

pytestmark = [pytest.mark.slow, pytest.mark.skipif(
    importlib.util.find_spec("gym_aloha") is None,
    reason="gym-aloha==0.1.5 is not installed beside demo (pip install --no-deps gym-aloha==0.1.5: its MJCF is the scene's)")]

ARMS = str(Path(__file__).resolve().parents[2] / "sim" / "assets" / "robots" / "aloha_vx300s.toml")
ENV = "demo.sim.aloha_scene:transfer_cube"


def _replays(store: EpisodeStore, i: int) -> None:
    assert_replays(store.read_episode(i), int(store.episode_info(i)["seed"]))


def test_sliders_move_both_followers_which_record_the_leaders(tmp_path: Path) -> None:
    out = tmp_path / "live.zarr"
    session = ArmsLeaderSession(ArmsLeaderConfig(env=ENV, robot=ARMS, out=str(out), port=0))
    client = None
    try:
        client = ViserWireClient(session.port)
        client.camera()
        client.pump(1.5)
        client.find("GuiImageMessage")  # the follower's top camera
        assert _wait_until(lambda: np.asarray(session.follower_view.image).std() > 5, 30.0)
        assert any(str((m.get("name") or "")).startswith("/leader") for m in client.messages)  # the leaders' ghosts
        client.click("Start")
        assert _wait_until(lambda: session.recording, 30.0)
        targets = {}
        for name, index in (("left.waist", 0), ("right.elbow", 9)):
            slider = client.find("GuiSliderMessage", **{"props.label": name})
            targets[index] = float(session.leader[index]) + 0.25
            client.send(vm.GuiUpdateMessage(uuid=slider["uuid"], updates={"value": targets[index]}))
        for index, target in targets.items():
            assert _wait_until(lambda: abs(session.env.frame()["obs.agent_pos"][index] - target) < 0.02, 40.0), index
        assert _wait_until(lambda: session.tracking_error < 0.02, 30.0)
        client.click("Stop & save")
        assert _wait_until(lambda: session.saved == 1, 30.0)
    finally:
        if client is not None:
            client.close()
        session.close()
    with EpisodeStore.open(out) as store:
        assert store.episode_info(0)["source"] == "leader" and store.meta.action.names[0] == "left.waist"
        ep = store.read_episode(0)
        for index, target in targets.items():
            assert np.isclose(ep["action"][:, index], target, atol=1e-3).any()  # the leader's joint, as the action
        _replays(store, 0)


def test_leaders_moved_along_the_experts_targets_hand_the_cube_over(tmp_path: Path) -> None:
    """The leaders moved (through the API the sliders use, one control step each, the simulation stepped here rather
    than by the real-time thread: the same steps on a loaded machine) along the bimanual expert's targets for the
    session's first episode: the followers transfer the cube, and the saved episode says so, holds the expert's
    actions and replays."""
    env = make_env("env:" + ENV)
    try:
        expert, info = foreign_episode(env, "demo.collect.aloha:transfer_cube", episode_seed(0, 0))
    finally:
        env.close()
    assert info["success"]
    leader = expert["action"].astype(np.float64)
    leader[:, [6, 13]] = 1.0 - leader[:, [6, 13]]  # gym-aloha's opening -> the sliders' closedness
    out = tmp_path / "live.zarr"
    session = ArmsLeaderSession(ArmsLeaderConfig(env=ENV, robot=ARMS, out=str(out), port=0), run_thread=False)
    try:
        session.press("start")
        for target in leader:
            session.set_leader(target)
            session.step()
        session.press("stop")
        assert _wait_until(lambda: session.saved == 1, 5.0)
    finally:
        session.close()
    with EpisodeStore.open(out) as store:
        assert bool(store.column("success")[0])
        np.testing.assert_allclose(store.read_episode(0)["action"], expert["action"], atol=1e-6)
        _replays(store, 0)


def test_the_page_renders_in_headless_chromium(tmp_path: Path) -> None:
    from tests.collect.test_teleop import CHROMIUM, page_drawn

    if CHROMIUM is None:
        pytest.skip("no chromium binary (apt-get install -y chromium); CI installs it")
    with ArmsLeaderSession(ArmsLeaderConfig(env=ENV, robot=ARMS, port=0)) as session:
        assert page_drawn(session.url, tmp_path / "leader_arms.png"), "the 3D view stayed blank"


def test_live_leaders_need_their_robot_and_a_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for argv, needle in [
        (["--env", ENV], "--env: live in an environment: --mode leader with --robot ARMS.toml"),
        (["--env", ENV, "--mode", "vr", "--robot", ARMS], "--mode leader with --robot ARMS.toml"),
        (["--env", "Pendulum-v1", "--mode", "leader", "--robot", ARMS], "--env Pendulum-v1: its action is a0"),
    ]:
        assert main(["teleop", *argv, "--port", "0", "--out", str(tmp_path / "x.zarr")]) != 0
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x.zarr").exists()
