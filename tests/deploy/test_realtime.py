"""The road to a robot (demo.deploy): the policy server answers what the policy itself computes, the
robot-side loop merges chunks, keeps its limits and holds when answers are late, and the whole loop runs
against the simulator stepping in real time in another process."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from websockets.sync.client import connect

from demo.cli.main import main
from demo.deploy.arm_model import ArmModel
from demo.deploy.controller import ChunkMerger, ChunkRequester, ControlConfig, Safety
from demo.deploy.protocol import decode, encode, pack_array, unpack_array
from demo.deploy.realtime import RealtimeConfig, run_realtime
from demo.deploy.server import PolicyServer, ServerConfig
from demo.errors import DemoError
from demo.policies.checkpoint import load_bundle
from demo.sim import make_env


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("deploy")
    assert main(["collect", "--task", "pick", "--episodes", "30", "--seed", "0", "--workers", "0",
                 "--out", str(root / "pick.zarr")]) == 0
    assert main(["train", str(root / "pick.zarr"), "--steps", "2000", "--out", str(root / "run")]) == 0
    return root / "run"


def test_arrays_travel_bit_for_bit() -> None:
    a = np.random.default_rng(0).normal(size=(2, 3, 4)).astype(np.float32)
    image = np.arange(64 * 64 * 3, dtype=np.uint8).reshape(64, 64, 3)
    message = decode(encode({"type": "obs", "frame": {"a": pack_array(a), "image": pack_array(image)}}))
    np.testing.assert_array_equal(unpack_array(message["frame"]["a"]), a)
    np.testing.assert_array_equal(unpack_array(message["frame"]["image"]), image)


def test_chunks_merge_with_acts_weights_and_expire() -> None:
    m = ChunkMerger(ensemble=0.5)
    assert m.action(0) is None
    m.add(0, np.zeros((4, 2)))
    m.add(2, np.ones((4, 2)))
    np.testing.assert_allclose(m.action(1), 0.0)
    w = np.exp(-0.5 * np.arange(2))
    np.testing.assert_allclose(m.action(3), w[1] / w.sum())  # the older chunk weighs more
    np.testing.assert_allclose(m.action(5), 1.0)  # the first has expired
    assert m.action(6) is None


def test_the_first_chunk_starts_when_it_is_first_used() -> None:
    """The robot held still until the episode's first answer came: that chunk starts at the step it is first
    executed, not at the step of the observation it answered; looking ahead (``planned``) moves nothing."""
    m = ChunkMerger(ensemble=0.01)
    m.add(0, np.arange(16.0)[:, None])
    assert m.planned(3)[0] == 3.0  # the chunk as filed: step 3 is its fourth action
    assert m.action(5)[0] == 0.0  # first executed at step 5: its first action
    assert m.action(6)[0] == 1.0 and m.planned(8)[0] == 3.0
    assert m.planned(40) is None and m.planned(7)[0] == 2.0  # looking past a chunk's end drops nothing
    committed = m.committed(6, 30)  # what the robot will do from step 6 until no chunk covers a step (step 21)
    np.testing.assert_array_equal(committed[:, 0], np.arange(1.0, 16.0))
    assert m.committed(21, 3) is None
    m.add(4, np.full((16, 1), 100.0))  # the next answers step 4's observation and is merged as filed
    assert 1.0 < m.action(7)[0] < 100.0
    m.reset()
    m.add(30, np.arange(16.0)[:, None])
    assert m.action(40)[0] == 0.0  # a new episode anchors its own first chunk


def test_safety_keeps_limits_and_speed() -> None:
    safety = Safety(np.array([[-1.0, 1.0], [-1.0, 1.0]]), max_joint_step=0.1)
    out = safety(np.array([5.0, -0.05, 1.7]), last=np.array([0.95, 0.0, 0.0]))
    np.testing.assert_allclose(out, [1.0, -0.05, 1.0])
    out = safety(np.array([-1.0, 0.0, 0.5]), last=np.array([0.5, 0.0, 0.0]))
    np.testing.assert_allclose(out, [0.4, 0.0, 0.5])  # at most 0.1 rad a step
    assert safety.clipped == 2


def test_safety_keeps_the_end_effector_over_the_table() -> None:
    """The client's own model of the arm: a command that would put the gripper into the table is held at the last
    command (the gripper part still obeys); one that stays over it passes."""
    arm = ArmModel("pick")
    box = arm.table_workspace()
    assert box[0, 2] == pytest.approx(0.0) and box[1, 2] == pytest.approx(0.6)  # the table top is z = 0
    env = make_env("pick")
    obs = env.reset(0)
    home = obs["obs.joint_pos"].astype(np.float64)
    np.testing.assert_allclose(arm.ee_position(home), obs["obs.ee_pos"], atol=1e-5)  # its kinematics are the scene's
    env.close()
    safety = Safety(arm.limits, max_joint_step=1.0, workspace=box, ee_position=arm.ee_position)
    last = np.r_[home, 0.0]
    lower = home.copy()
    lower[1] += 1.1  # the shoulder pitched forward: the hand goes down through the table top
    assert arm.ee_position(lower)[2] < 0
    np.testing.assert_allclose(safety(np.r_[lower, 1.0], last), np.r_[home, 1.0])
    assert safety.outside == 1 and safety.clipped == 1
    nudged = home + 0.02
    assert box[0, 2] < arm.ee_position(nudged)[2] and np.all(arm.ee_position(nudged) < box[1])
    np.testing.assert_allclose(safety(np.r_[nudged, 0.0], last), np.r_[nudged, 0.0])
    assert safety.outside == 1


def test_the_server_answers_the_policys_own_chunk(run: Path) -> None:
    server = PolicyServer(ServerConfig(str(run), port=0)).start()
    try:
        env = make_env("pick")
        frame = env.reset(123)
        actor = load_bundle(run).actor()
        actor.reset(0)
        expected = actor.chunk(frame)
        with connect(server.url) as ws:
            ws.send(encode({"type": "reset", "seed": 0}))
            assert decode(ws.recv())["type"] == "ready"
            ws.send(encode({"type": "obs", "seq": 7, "t_obs": 1.5, "frame": {k: pack_array(v) for k, v in frame.items()}}))
            answer = decode(ws.recv())
            assert (answer["type"], answer["seq"], answer["t_obs"]) == ("chunk", 7, 1.5)
            np.testing.assert_allclose(unpack_array(answer["chunk"]), expected, atol=1e-6)
            ws.send(encode({"type": "obs", "seq": 8, "t_obs": 2.0, "frame": {}}))  # no observations at all
            assert decode(ws.recv())["type"] == "error"
        env.close()
    finally:
        server.close()
    with pytest.raises(DemoError, match="cannot connect to the policy server"):
        ChunkRequester(server.url, ChunkMerger(0.01))


def test_the_server_continues_a_committed_prefix_and_refuses_a_malformed_one(run: Path) -> None:
    """A policy trained with --prefix-steps says so at reset and starts its chunk with the robot's committed
    actions; a prefix of the wrong width is a one-line error in the log and the connection keeps serving. An
    ordinary policy says 0 and ignores a prefix."""
    prefixed = run.parent / "prefixed"
    if not prefixed.exists():
        assert main(["train", str(run.parent / "pick.zarr"), "--steps", "300", "--prefix-steps", "4",
                     "--out", str(prefixed)]) == 0
    env = make_env("pick")
    frame = {k: pack_array(v) for k, v in env.reset(3).items()}
    env.close()
    committed = np.tile(np.r_[np.linspace(0.1, 0.7, 7), 0.0].astype(np.float32), (6, 1))
    for path, steps in ((prefixed, 4), (run, 0)):
        lines: list[str] = []
        server = PolicyServer(ServerConfig(str(path), port=0), log=lines.append).start()
        try:
            with connect(server.url) as ws:
                ws.send(encode({"type": "reset", "seed": 0}))
                assert decode(ws.recv())["prefix_steps"] == steps
                ws.send(encode({"type": "obs", "seq": 0, "t_obs": 0.0, "frame": frame}))
                plain = unpack_array(decode(ws.recv())["chunk"])
                ws.send(encode({"type": "reset", "seed": 0}))
                decode(ws.recv())
                ws.send(encode({"type": "obs", "seq": 0, "t_obs": 0.0, "frame": frame, "prefix": pack_array(committed)}))
                told = unpack_array(decode(ws.recv())["chunk"])
                if steps:
                    np.testing.assert_array_equal(told[:steps], committed[:steps])
                    assert np.abs(told[steps:] - plain[steps:]).max() > 1e-4
                else:
                    np.testing.assert_array_equal(told, plain)
                ws.send(encode({"type": "obs", "seq": 1, "t_obs": 0.0, "frame": frame,
                                "prefix": pack_array(committed[:, :3])}))
                answer = decode(ws.recv())
                assert answer["type"] == "error" and "the prefix must be finite [steps, 8]" in answer["problem"]
                ws.send(encode({"type": "obs", "seq": 2, "t_obs": 0.0, "frame": frame}))
                assert decode(ws.recv())["type"] == "chunk"  # still serving
        finally:
            server.close()
        assert any("the prefix must be finite" in line for line in lines) and all("\n" not in x for x in lines)


def test_the_loop_in_real_time_with_late_answers(run: Path) -> None:
    fast = run_realtime(RealtimeConfig(str(run), episodes=3, control=ControlConfig(network_s=0.01)))
    assert fast["episodes"] == 3 and fast["successes"] >= 1
    assert fast["round_trip_ms"]["median"] >= 20  # the injected 10 ms each way
    slow = run_realtime(RealtimeConfig(str(run), episodes=1, inference_delay_s=1.2))
    # Answers 1.2 s late, chunks of 16 steps (0.8 s): the loop holds, stalling, rather than guess.
    assert slow["stall_steps"] > 0.3 * slow["steps"] and slow["round_trip_ms"]["median"] >= 1200
    # The baseline that waits: at 0.3 s a step, the loop acts a fraction of the robot's 20 Hz ticks.
    waiting = run_realtime(RealtimeConfig(str(run), episodes=1, inference_delay_s=0.3,
                                          control=ControlConfig(synchronous=True)))
    assert waiting["loop_overruns"] > 0 and waiting["steps"] < 0.5 * 160


def test_bench_realtime_writes_every_delay(run: Path, tmp_path: Path) -> None:
    out = tmp_path / "rt.json"
    assert main(["bench", "realtime", str(run), "--episodes", "1", "--delays-ms", "0,100", "--network-ms", "5",
                 "--json", str(out)]) == 0
    import json

    results = json.loads(out.read_text())["results"]
    assert [r["inference_delay_ms"] for r in results] == [0.0, 100.0] and all(r["episodes"] == 1 for r in results)
    assert results[1]["round_trip_ms"]["median"] > results[0]["round_trip_ms"]["median"] + 80


def test_without_delay_the_simulated_client_is_demo_eval(run: Path, tmp_path: Path) -> None:
    """``demo bench delay``'s client at delay 0 asks for a chunk every step and merges them with ACT's weights, as
    ``demo eval`` executes the run: the same episodes, step for step. With a delay the episodes change, and the same
    seed replays them exactly."""
    from demo.deploy.delayed import DelayConfig, run_delayed
    from demo.evaluation.evaluate import EvalConfig, evaluate

    reference = evaluate(EvalConfig(run=str(run), episodes=4, device="cpu"))
    now = run_delayed(DelayConfig(str(run), delay_steps=0, episodes=4))
    assert now["successes"] == reference["successes"]
    assert now["episode_lengths"] == [d["length"] for d in reference["episodes_detail"]]
    late = run_delayed(DelayConfig(str(run), delay_steps=5, episodes=4))
    assert late["episode_lengths"] != now["episode_lengths"]
    out = tmp_path / "delay.json"
    figure = tmp_path / "delay.png"
    assert main(["bench", "delay", str(run), str(run), "--delays", "5", "--episodes", "4", "--plot", str(figure),
                 "--json", str(out)]) == 0
    import json

    written = json.loads(out.read_text())
    assert [r["episode_lengths"] for r in written["results"]] == [late["episode_lengths"]] * 2  # one per run
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and written["plot"] == str(figure)
    assert main(["bench", "delay", str(run), "--delays", "-1"]) != 0


def test_demo_serve_listens_on_loopback(run: Path) -> None:
    child = subprocess.Popen([sys.executable, "-m", "demo", "serve", str(run), "--port", "0"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env={**os.environ, "COLUMNS": "200"})
    try:
        line = child.stdout.readline()
        assert "serving" in line and "ws://127.0.0.1:" in line
        url = line.split(" at ")[1].split()[0]
        with connect(url) as ws:
            ws.send(encode({"type": "reset", "seed": 0}))
            assert decode(ws.recv())["type"] == "ready"
    finally:
        child.terminate()
        child.wait(timeout=20)
    time.sleep(0.1)


def test_bad_input_to_the_server(run: Path) -> None:
    """Malformed, truncated and ill-shaped messages, two clients at once and one vanishing mid-request: one
    line each in the server's log, an error answer, and the server keeps serving."""
    lines: list[str] = []
    server = PolicyServer(ServerConfig(str(run), port=0), log=lines.append).start()
    frame = make_env("pick").reset(5)
    good = encode({"type": "obs", "seq": 1, "t_obs": 0.0, "frame": {k: pack_array(v) for k, v in frame.items()}})
    wrong_shape = {**frame, "obs.joint_pos": np.zeros(3, np.float32)}
    wrong_dtype = {k: pack_array(v) for k, v in frame.items()}
    wrong_dtype["obs.joint_pos"] = ["|S3", [7], b"x" * 21]
    try:
        with connect(server.url) as a, connect(server.url) as b:
            for bad, needle in [(b"\x93garbage", "MsgspecError|DecodeError|ValueError"), (good[:40], "Decode|Error"),
                                (encode({"type": "obs", "seq": 2, "t_obs": 0.0, "frame": {k: pack_array(v) for k, v in
                                                                                        wrong_shape.items()}}),
                                 "obs.joint_pos is"),
                                (encode({"type": "obs", "seq": 3, "t_obs": 0.0, "frame": wrong_dtype}), "Error"),
                                (encode({"type": "nonsense"}), "unknown message type")]:
                a.send(bad)
                answer = decode(a.recv())
                assert answer["type"] == "error", bad[:20]
                b.send(good)  # the other client is served meanwhile
                assert decode(b.recv())["type"] == "chunk"
        vanishing = connect(server.url)
        vanishing.send(good)
        vanishing.close()  # before reading the answer
        with connect(server.url) as c:
            c.send(good)
            assert decode(c.recv())["type"] == "chunk"
    finally:
        server.close()
    assert len([line for line in lines if "disconnected" not in line]) == 5
    assert all("\n" not in line and "Traceback" not in line for line in lines)
    with pytest.raises(DemoError, match="pass --expose"):
        PolicyServer(ServerConfig(str(run), host="0.0.0.0", port=0))


def test_bench_serve_times_the_server_against_the_inference(run: Path) -> None:
    """`demo bench serve`: a round trip holds an inference, so its median is at least the inference's minimum;
    percentiles are ordered; several clients at once are all answered."""
    from demo.bench.serve import ServeBenchConfig, run as run_serve

    result = run_serve(ServeBenchConfig(runs=(str(run),), seconds=0.5, clients=3))
    (r,) = result["results"]
    assert r["policy"] == "bc" and r["message_bytes"] > 100
    rt, inf = r["round_trip_ms"], r["inference_ms"]
    assert rt["min"] <= rt["median"] <= rt["p90"] <= rt["p99"] and rt["calls"] >= 50 and inf["calls"] >= 50
    assert rt["median"] >= inf["min"] and 0 < r["ratio"] < 1.5
    assert r["queries_per_s"] > 0 and r["queries_per_s_under_load"] > 0
