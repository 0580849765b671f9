"""VR-style collection: pose-file parsing, calibration, clutch, smoothing, and the headline check:
scripted `pick` paths re-expressed in a tracker frame (rotation, offset, scale 1.3, mm noise)
retarget into demonstrations with >= 90% success."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.collect.human import InputEpisode
from demo.collect.human_files import TrackerFrame, write_human_files
from demo.collect.vr import (
    Calibration,
    HandMapper,
    PoseTrack,
    SmoothingParams,
    collect_vr,
    load_calibration,
    parse_poses,
    resample,
    smooth,
)
from demo.errors import DemoError
from demo.seeds import episode_seed
from demo.sim.geometry import axis_angle_quat, quat_angle, quat_mul
from demo.store import EpisodeStore

EPISODES = 10


@pytest.fixture(scope="module")
def human_files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("human")
    summary = write_human_files(out, "pick", episodes=EPISODES, seed=7)
    assert summary["scripted_successes"] == EPISODES
    return out


def _pose(t: float, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), grip=0.0, **extra) -> str:
    return json.dumps({"t": t, "pos": list(pos), "quat": list(quat), "grip": grip, **extra})


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


# ------------------------------------------------------------------------------ the headline
@pytest.mark.slow
def test_synthetic_pose_file_retargets_into_successful_demos(human_files: Path, tmp_path: Path) -> None:
    out = tmp_path / "vr.zarr"
    result = collect_vr("pick", human_files / "POSES.jsonl", out, scale=1 / TrackerFrame().scale, operator="tester")
    assert result.episodes == EPISODES
    assert result.success_rate >= 0.9, result
    store = EpisodeStore.open(out)
    table = store.table.to_pylist()
    assert {r["source"] for r in table} == {"vr"}
    assert {r["operator"] for r in table} == {"tester"}
    assert all(r["unreachable_frames"] == 0 for r in table)
    for key in ("info.ik_ok", "info.ik_error", "info.ee_target", "sim.state", "obs.joint_pos"):
        assert key in store.meta.features
    ep = store.read_episode(0)
    assert ep["info.ik_ok"].dtype == bool and ep["info.ik_ok"].all()
    assert ep["info.ik_error"][:, 0].max() < 0.01
    # The header's episode_seed reproduces the scripted episode's initial state.
    seeds = [episode_seed(7, i) for i in range(EPISODES)]
    assert store.column("seed").tolist() == seeds
    from demo.sim import make_env

    env = make_env("pick")
    env.reset(seeds[0])
    np.testing.assert_allclose(ep["obs.object_pos"][0], env.observe()["obs.object_pos"], atol=1e-6)
    env.close()
    store.close()


@pytest.mark.slow
def test_calibration_file_maps_absolute_poses(human_files: Path, tmp_path: Path) -> None:
    """With the exact CALIB.json the hand maps onto the recorded EE path (no first-pose alignment)."""
    tracks = parse_poses(human_files / "POSES.jsonl")[:3]
    lines = []
    for tr in tracks:
        lines.append(json.dumps({"episode_seed": tr.episode.seed}))
        lines += [_pose(float(t), p.tolist(), q.tolist(), float(g)) for t, p, q, g in zip(tr.t, tr.pos, tr.quat, tr.grip)]
    small = _write(tmp_path / "three.jsonl", lines)
    result = collect_vr("pick", small, tmp_path / "calib.zarr", calib=human_files / "CALIB.json")
    assert result.successes >= 2, result


# ------------------------------------------------------------------------------ parsing
@pytest.mark.parametrize(
    "bad_line, message",
    [
        ('{"t": 0.1, "pos": [0, 0', "not valid JSON"),
        (_pose(0.1, quat=(1.0, 0.2, 0.0, 0.0)), "not unit length"),
        (_pose(0.01), "goes backwards"),
        (_pose(0.02), "repeats"),
        ('{"t": 0.1, "pos": [NaN, 0, 0], "quat": [1, 0, 0, 0], "grip": 0}', "NaN"),
        (_pose(0.1, pos=(0.0, 0.0)), "list of 3 numbers"),
        (_pose(0.1, grip=1.5), "within 0 (open) .. 1 (closed)"),
        (_pose(0.1, engaged="yes"), "'engaged' must be true or false"),
        (_pose(0.1, speed=1.0), "unknown key"),
        ('{"t": 0.1, "pos": [0, 0, 0], "grip": 0}', "lacks quat"),
        ('[1, 2, 3]', "expected a JSON object"),
        ('{"episode_seed": -3}', "non-negative integer"),
    ],
)
def test_bad_lines_name_file_and_line_and_write_nothing(tmp_path: Path, bad_line: str, message: str) -> None:
    path = _write(tmp_path / "bad.jsonl", ['{"episode_seed": 5}', _pose(0.0), _pose(0.02), "", bad_line, _pose(0.5)])
    out = tmp_path / "out.zarr"
    with pytest.raises(DemoError) as info:
        collect_vr("pick", path, out)
    assert info.value.where == f"{path}:5"
    assert message in info.value.problem
    assert not out.exists()  # parsed before the store is created


@pytest.mark.slow
def test_bad_file_leaves_existing_store_untouched(human_files: Path, tmp_path: Path) -> None:
    good = _write(tmp_path / "good.jsonl", ['{"episode_seed": 11}', *[_pose(i / 30) for i in range(10)]])
    out = tmp_path / "s.zarr"
    collect_vr("pick", good, out)
    before = EpisodeStore.open(out)
    n, frames = before.num_episodes, before.num_frames
    before.close()
    bad = _write(tmp_path / "bad.jsonl", ['{"episode_seed": 12}', _pose(0.0), _pose(0.1, pos=(float("inf"), 0, 0))])
    with pytest.raises(DemoError, match="bad.jsonl:3"):
        collect_vr("pick", bad, out, append=True)
    after = EpisodeStore.open(out)
    assert (after.num_episodes, after.num_frames) == (n, frames)
    assert after.verify() == []
    after.close()


def test_headers_split_episodes_and_name_seeds(tmp_path: Path) -> None:
    path = _write(tmp_path / "p.jsonl", [
        _pose(0.0), _pose(0.1),
        '{"episode_seed": 42, "operator": "alice", "task": "pick"}', _pose(5.0), _pose(5.1), _pose(5.2),
    ])
    tracks = parse_poses(path, "pick")
    assert [len(t.t) for t in tracks] == [2, 3]
    assert tracks[0].episode == InputEpisode(1, None, None)
    assert tracks[1].episode == InputEpisode(3, 42, "alice")
    with pytest.raises(DemoError, match="recorded for task 'pick', not 'push'"):
        parse_poses(path, "push")
    empty = _write(tmp_path / "e.jsonl", ['{"episode_seed": 1}', '{"episode_seed": 2}', _pose(0.0)])
    with pytest.raises(DemoError, match="e.jsonl:1: episode has no poses"):
        parse_poses(empty)
    with pytest.raises(DemoError, match="no poses"):
        parse_poses(_write(tmp_path / "blank.jsonl", [""]))


def test_calibration_file_errors(tmp_path: Path) -> None:
    def calib(obj: object) -> Path:
        p = tmp_path / "c.json"
        p.write_text(json.dumps(obj))
        return p

    with pytest.raises(DemoError, match="lacks 'translation'"):
        load_calibration(calib({"rotation": [1, 0, 0, 0]}))
    with pytest.raises(DemoError, match="not a unit quaternion"):
        load_calibration(calib({"rotation": [1, 1, 0, 0], "translation": [0, 0, 0]}))
    with pytest.raises(DemoError, match="not a rotation"):
        load_calibration(calib({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "translation": [0, 0, 0]}))
    c = load_calibration(calib({"rotation": [[0, -1, 0], [1, 0, 0], [0, 0, 1]], "translation": [1, 2, 3], "scale": 0.5}))
    np.testing.assert_allclose(abs(c.rotation), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-9)


# ------------------------------------------------------------------------------ mapping
def _robot_pose() -> tuple[np.ndarray, np.ndarray]:
    return np.array([0.5, 0.0, 0.3]), np.array([0.0, 1.0, 0.0, 0.0])


def test_align_mode_anchors_first_pose_and_scales_motion() -> None:
    mapper = HandMapper(None, scale=0.5)
    q_hand = axis_angle_quat(np.array([0.0, 0.0, 1.0]), 0.7)  # tracker frame yawed vs the base
    p0, q0 = mapper(np.array([1.0, 2.0, 3.0]), q_hand, True, _robot_pose)
    np.testing.assert_allclose(p0, [0.5, 0.0, 0.3])
    assert quat_angle(q0, _robot_pose()[1]) < 1e-9
    # Moving the hand 0.2 along its own x moves the EE 0.1 along the EE's x (the aligned frame).
    p1, q1 = mapper(np.array([1.0, 2.0, 3.0]) + 0.2 * np.array([np.cos(0.7), np.sin(0.7), 0.0]), q_hand, True, _robot_pose)
    np.testing.assert_allclose(p1 - p0, [0.1, 0.0, 0.0], atol=1e-9)
    # Rotations are not scaled: a 0.3 rad hand turn turns the EE 0.3 rad.
    turn = quat_mul(axis_angle_quat(np.array([0.0, 0.0, 1.0]), 0.3), q_hand)
    _, q2 = mapper(np.array([1.0, 2.0, 3.0]), turn, True, _robot_pose)
    assert quat_angle(q2, q0) == pytest.approx(0.3, abs=1e-9)


def test_clutch_holds_and_reanchors_without_a_jump() -> None:
    mapper = HandMapper(None, scale=1.0)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    robot = {"pose": _robot_pose()}
    mapper(np.zeros(3), q, True, lambda: robot["pose"])
    moved, _ = mapper(np.array([0.0, 0.1, 0.0]), q, True, lambda: robot["pose"])
    assert mapper(np.array([5.0, 5.0, 5.0]), q, False, lambda: robot["pose"]) is None  # clutch held: hold
    robot["pose"] = (moved, _robot_pose()[1])
    back, _ = mapper(np.array([5.0, 5.0, 5.0]), q, True, lambda: robot["pose"])  # re-engage far away
    np.testing.assert_allclose(back, moved)  # no jump: anchored where the robot is
    later, _ = mapper(np.array([5.0, 5.05, 5.0]), q, True, lambda: robot["pose"])
    np.testing.assert_allclose(later - back, [0.0, -0.05, 0.0], atol=1e-9)  # tracker y -> -EE y (EE faces down)


def test_absolute_calibration_inverts_the_tracker_frame() -> None:
    frame = TrackerFrame()
    c = frame.calibration()
    cal = Calibration(np.array(c["rotation"]), np.array(c["translation"]), c["scale"])
    mapper = HandMapper(cal, 1.0)
    p_base = np.array([0.45, -0.1, 0.2])
    q_base = axis_angle_quat(np.array([1.0, 0.0, 0.0]), np.pi)
    rot = np.array(frame.rotation)
    from demo.collect.vr import _rotate

    p_tr = np.array(frame.offset) + frame.scale * _rotate(rot, p_base)
    q_tr = quat_mul(rot, q_base)
    p, q = mapper(p_tr, q_tr, True, lambda: (np.zeros(3), np.array([1.0, 0, 0, 0])))
    np.testing.assert_allclose(p, p_base, atol=1e-9)
    assert quat_angle(q, q_base) < 1e-9


# ------------------------------------------------------------------------------ smoothing, resampling
def _track(t: np.ndarray, pos: np.ndarray, engaged: np.ndarray | None = None) -> PoseTrack:
    n = len(t)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    eng = np.ones(n, dtype=bool) if engaged is None else engaged
    return PoseTrack(InputEpisode(1, None, None), t, pos, quat, np.zeros(n), eng)


def test_one_euro_removes_jitter_with_little_lag() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(600) / 60.0
    still = _track(t, np.zeros((600, 3)) + rng.normal(0, 0.003, (600, 3)))
    out = smooth(still)
    assert out.pos[60:].std() < 0.4 * still.pos[60:].std()
    # A hand moving at 0.3 m/s: the filter lags by well under the distance of one 20 Hz step.
    ramp = _track(t, np.stack([0.3 * t, np.zeros(600), np.zeros(600)], axis=1))
    lag = ramp.pos[100:, 0] - smooth(ramp).pos[100:, 0]
    assert 0 <= lag.max() < 0.3 / 20
    assert smooth(still, SmoothingParams(min_cutoff=0.0)) is still  # off


def test_resample_to_control_rate() -> None:
    t = np.array([0.0, 0.04, 0.11, 0.2, 0.31])
    pos = np.stack([t, 2 * t, np.zeros(5)], axis=1)
    engaged = np.array([True, True, True, False, True])
    s = resample(_track(t, pos, engaged), 20.0)
    assert len(s) == 7  # 0 .. 0.30 s
    np.testing.assert_allclose(s.pos[1], [0.05, 0.10, 0.0])  # interpolated between engaged samples
    np.testing.assert_allclose(s.pos[3], [0.11, 0.22, 0.0])  # next sample disengaged: held, not blended
    np.testing.assert_allclose(s.pos[5], [0.20, 0.40, 0.0])  # latest sample (clutch released) holds
    assert s.engaged.tolist() == [True, True, True, True, False, False, False]
