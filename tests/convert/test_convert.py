"""`demo convert` on a scripted pick store: new store, metadata, round trip, every pair, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.convert import representations as reps
from demo.convert.check import round_trip
from demo.convert.context import load_context
from demo.convert.convert import ConvertOptions, Converter, convert_store, episode_anchors
from demo.convert.representations import Segments
from demo.errors import DemoError
from demo.sim import geometry as rot
from demo.store import ActionSpec, EpisodeStore


@pytest.fixture(scope="module")
def pick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.collect.scripted import CollectConfig, collect_scripted

    out = tmp_path_factory.mktemp("convert") / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=3, seed=0), out)
    return out


def _tree_bytes(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file() and p.name != ".lock"}


def test_to_ee7_writes_a_new_store_with_metadata_and_provenance(pick: Path, tmp_path: Path):
    before = _tree_bytes(pick)
    result = convert_store(pick, tmp_path / "ee7.zarr", ConvertOptions(to="ee7"))
    assert _tree_bytes(pick) == before  # the source is untouched
    assert result.frames > 0 and result.anchor_source == {"sim.state": 3}
    assert result.fk_check is not None and result.fk_check["max_pos_err_m"] < 1e-12
    with EpisodeStore.open(pick) as src, EpisodeStore.open(tmp_path / "ee7.zarr") as out:
        assert out.meta.action.name == "ee7"
        assert out.meta.action.names == ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper")
        assert out.meta.robot == src.meta.robot and out.meta.task == src.meta.task
        record = out.meta.provenance[-1]
        assert record["op"] == "convert" and record["from"] == str(pick) and record["to"] == "ee7"
        assert record["from_action"]["name"] == "joint_pos" and record["robot"]["name"] == "panda_prim"
        assert reps.EE_ANCHOR_KEY in out.meta.features
        assert out.num_episodes == src.num_episodes
        assert np.array_equal(out.column("success"), src.column("success"))
        assert np.array_equal(out.column("seed"), src.column("seed"))
        for i in range(src.num_episodes):
            a, b = src.read_episode(i), out.read_episode(i)
            for key in ("obs.joint_pos", "obs.ee_pos", "sim.state", "info.ee_target"):
                assert np.array_equal(a[key], b[key])
            # The anchor is the measured EE pose at frame 0 (the env recorded it as obs.ee_*).
            anchor = b[reps.EE_ANCHOR_KEY]
            assert np.all(anchor == anchor[0])
            assert np.abs(anchor[0, :3] - a["obs.ee_pos"][0]).max() < 1e-6
            assert rot.angle_between(rot.quat_to_mat(anchor[0, 3:]), rot.quat_to_mat(a["obs.ee_quat"][0])) < 1e-5
            # Frame 0's translation is from the measured pose to the first commanded pose.
            assert not np.allclose(b["action"][0, :3], 0.0)


def test_round_trip_meets_the_issue_bounds(pick: Path, tmp_path: Path):
    rt = round_trip(pick, ConvertOptions(to="ee7"))
    assert rt.ik["converged_share"] >= 0.999
    assert rt.max_pos_err_m <= 1e-4 and rt.max_rot_err_rad <= 1e-3
    assert rt.fk_vs_mujoco["max_pos_err_m"] < 1e-12
    # The same through stores: joint_pos -> ee7 -> joint_pos, compared by FK.
    convert_store(pick, tmp_path / "ee7.zarr", ConvertOptions(to="ee7"))
    result = convert_store(tmp_path / "ee7.zarr", tmp_path / "back.zarr", ConvertOptions(to="joint_pos"))
    assert result.ik is not None and result.ik.converged_share >= 0.999
    with EpisodeStore.open(pick) as src, EpisodeStore.open(tmp_path / "back.zarr") as back:
        ctx = load_context(src.meta, pick)
        assert back.meta.action == src.meta.action  # the environment's own joint_pos spec
        assert "ik_failed_frames" in back.table.column_names
        for i in range(src.num_episodes):
            a, b = src.read_episode(i), back.read_episode(i)
            ok = b["info.ik_converged"]
            p0, R0 = ctx.kin.fk(a["action"][:, :7])
            p1, R1 = ctx.kin.fk(b["action"][:, :7])
            assert np.linalg.norm(p1 - p0, axis=1)[ok].max() <= 1e-4
            assert rot.angle_between(R1, R0)[ok].max() <= 1e-3
            assert np.array_equal(a["action"][:, 7], b["action"][:, 7])  # gripper unchanged
            # IK warm-started from the measured joints keeps the arm's null-space posture: no drift.
            assert np.abs(b["action"][:, :7] - a["action"][:, :7]).max() < 0.1


FORMATS = [("joint_pos", {}), ("joint_vel", {}), ("ee_abs", {"rotation": "rot6d"}), ("ee_abs", {"rotation": "euler"}),
           ("ee_abs", {"rotation": "rotvec"}), ("ee_delta", {}), ("ee_delta", {"delta_frame": "ee"}), ("ee7", {})]


def test_every_representation_pair_agrees_with_the_direct_conversion(pick: Path):
    """A -> B equals joint_pos -> B for every pair (compared as commanded EE poses)."""
    with EpisodeStore.open(pick) as store:
        ctx = load_context(store.meta, pick)
        episodes = [store.read_episode(i) for i in range(2)]
        fps = store.meta.fps
    seg = Segments(np.cumsum([len(e["action"]) for e in episodes]))
    jp = reps.make_format("joint_pos", joint_names=ctx.robot.arm_joints)
    anchor, _ = episode_anchors(episodes, ctx, jp, "test")
    action = np.concatenate([e["action"] for e in episodes])
    fmts = [reps.make_format(n, joint_names=ctx.robot.arm_joints, **kw) for n, kw in FORMATS]
    direct = {i: Converter(jp, f, fps, ctx).convert(action, anchor, seg)[0].astype(np.float32) for i, f in enumerate(fmts)}

    def poses(fmt: reps.ActionFormat, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        track = reps.decode(fmt, a, fps, anchor, seg)
        return ctx.kin.fk(track.q) if isinstance(track, reps.JointTrack) else (track.pos, track.rot)

    for i, fa in enumerate(fmts):
        for j, fb in enumerate(fmts):
            converted, ik = Converter(fa, fb, fps, ctx).convert(direct[i], anchor, seg)
            p, R = poses(fb, converted)
            p_ref, R_ref = poses(fb, direct[j])
            assert np.abs(p - p_ref).max() < 1e-4, (fa.name, fb.name)
            assert rot.angle_between(R, R_ref).max() < 1e-3, (fa.name, fb.name)
            assert np.array_equal(converted[:, -1], direct[j][:, -1])
            if ik is not None:
                assert all(r.converged.mean() >= 0.999 for r in ik)


def test_a_store_without_a_robot_fails_clearly(pick: Path, tmp_path: Path):
    with EpisodeStore.open(pick) as store:
        meta = type(store.meta).from_json(store.meta.to_json())
        meta.robot = None
        store.copy_to(tmp_path / "norobot.zarr", meta=meta).close()
    with pytest.raises(DemoError, match="names no robot.*converting joint_pos to ee7 needs the robot's kinematics"):
        convert_store(tmp_path / "norobot.zarr", tmp_path / "x.zarr", ConvertOptions(to="ee7"))
    assert not (tmp_path / "x.zarr").exists()
    # joint_pos -> joint_vel needs no kinematics: it works without a robot (anchor = first command).
    result = convert_store(tmp_path / "norobot.zarr", tmp_path / "jv.zarr", ConvertOptions(to="joint_vel"))
    assert result.anchor_source == {"first_command": 3}
    # Naming the robot on the command line works.
    from demo.sim.robot import BUILTIN_CONFIG

    result = convert_store(tmp_path / "norobot.zarr", tmp_path / "y.zarr", ConvertOptions(to="ee7", robot=str(BUILTIN_CONFIG)))
    assert result.anchor_source == {"sim.state": 3}


def test_frames_where_ik_fails_are_flagged(pick: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    convert_store(pick, tmp_path / "abs.zarr", ConvertOptions(to="ee_abs", rotation="euler"))
    with EpisodeStore.open(tmp_path / "abs.zarr") as store:
        data = store.read_episode(1)
        data["action"][10, 0] = 2.0  # 2 m in front of the robot: out of reach
        with EpisodeStore.create(tmp_path / "bad.zarr", store.meta) as bad:
            bad.append_episodes([(store.read_episode(0), {"success": True}), (data, {"success": True})])
    assert main(["convert", str(tmp_path / "bad.zarr"), "--to", "joint_pos", "--out", str(tmp_path / "jp.zarr")]) == 0
    assert "IK not converged" in capsys.readouterr().out
    with EpisodeStore.open(tmp_path / "jp.zarr") as out:
        assert out.column("ik_failed_frames").tolist() == [0, 1]
        assert out.column("ik_max_pos_err")[1] > 1.0
        ok = out.read_episode(1)["info.ik_converged"]
        assert not ok[10] and ok[:10].all() and ok[12:].all()  # the next frame may still be recovering
        record = out.meta.provenance[-1]["ik"]
        assert record["failed"]["1"][0] == 10 and record["converged"] == record["frames"] - len(record["failed"]["1"])


def test_an_action_spec_with_the_wrong_dimension_is_refused(pick: Path, tmp_path: Path):
    with EpisodeStore.open(pick) as store:
        meta = type(store.meta).from_json(store.meta.to_json())
        bad = ActionSpec("ee7", names=tuple(f"a{i}" for i in range(8)), units=("1",) * 8)
        meta.action = bad
        meta.features["action"] = bad.feature()
        store.copy_to(tmp_path / "bad.zarr", meta=meta).close()
    with pytest.raises(DemoError, match="ee7 should have 7 dimensions, the metadata says 8"):
        convert_store(tmp_path / "bad.zarr", tmp_path / "x.zarr", ConvertOptions(to="joint_pos"))


def test_cli(pick: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    out = tmp_path / "abs.zarr"
    assert main(["convert", str(pick), "--to", "ee_abs", "--rotation", "rot6d", "--out", str(out),
                 "--round-trip", "--json", str(tmp_path / "r.json")]) == 0
    text = capsys.readouterr().out
    assert "joint_pos -> ee_abs" in text and "IK converged" in text
    with EpisodeStore.open(out) as store:
        assert store.meta.action.name == "ee_abs" and store.meta.action.params["rotation"] == "rot6d"
    import json

    report = json.loads((tmp_path / "r.json").read_text())
    assert report["convert"]["target"] == "ee_abs" and report["round_trip"]["ik"]["converged_share"] >= 0.999
    assert main(["convert", str(pick), "--to", "ee9", "--out", str(tmp_path / "y.zarr")]) == 1
    assert "unknown action representation 'ee9'" in capsys.readouterr().err
    assert main(["convert", str(pick), "--to", "ee7", "--rotation", "rot6d", "--out", str(tmp_path / "z.zarr")]) == 1
    assert "ee7 takes rotation euler" in capsys.readouterr().err
    assert main(["convert", str(pick), "--to", "ee7"]) == 1  # nothing to do: no --out, --check or --round-trip
    assert main(["convert", str(pick), "--to", "ee7", "--out", str(out)]) == 1  # exists, no --overwrite
    assert "already exists" in capsys.readouterr().err


def test_progress_ticks_count_frames_and_episodes(pick: Path, tmp_path: Path):
    from demo.progress import Tick

    ticks: list[Tick] = []
    result = convert_store(pick, tmp_path / "jv.zarr", ConvertOptions(to="joint_vel"), progress=ticks.append)
    assert {t.stage for t in ticks} == {"convert -> joint_vel"} and {t.total for t in ticks} == {result.frames}
    assert ticks[0].done == 0 and ticks[-1].done == result.frames and ticks[-1].fields["episodes"] == 3
    ticks.clear()
    round_trip(pick, ConvertOptions(to="ee7"), episodes=[0, 2], progress=ticks.append)
    assert [(t.stage, t.done, t.total) for t in ticks] == [("round trip", i, 2) for i in range(3)]
