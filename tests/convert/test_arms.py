"""ee7 for each arm of gym-aloha's pair (demo's rebuild of its scene): converted, written, and replayed back."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.store import EpisodeStore

pytestmark = pytest.mark.skipif(importlib.util.find_spec("gym_aloha") is None,
                                reason="gym-aloha==0.1.5 is not installed beside demo (pip install --no-deps "
                                       "gym-aloha==0.1.5: its MJCF is the scene's)")

ARMS = str(Path(__file__).resolve().parents[2] / "sim" / "assets" / "robots" / "aloha_vx300s.toml")


@pytest.fixture(scope="module")
def scene_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("arms") / "tc.zarr"
    assert main(["collect", "--env", "demo.sim.aloha_scene:transfer_cube", "--expert", "demo.collect.aloha:transfer_cube",
                 "--episodes", "2", "--seed", "3", "--workers", "0", "--out", str(path)]) == 0
    return path


def test_each_arm_s_ee7_replays_as_the_joint_targets_do(scene_store: Path, tmp_path: Path) -> None:
    out, report = tmp_path / "ee7.zarr", tmp_path / "check.json"
    assert main(["convert", str(scene_store), "--to", "ee7", "--robot", ARMS, "--out", str(out), "--check",
                 "--json", str(report)]) == 0
    check = json.loads(report.read_text())["check"]["summary"]
    assert check["episodes"] == 2 and check["success_agreement"] == 1.0 and check["converted_successes"] == 2
    assert check["max_pos_err_m"] < 1e-4 and check["max_rot_err_rad"] < 1e-3  # both arms' TCPs, over both replays
    with EpisodeStore.open(out) as converted, EpisodeStore.open(scene_store) as source:
        spec = converted.meta.action
        assert spec.name == "ee7" and spec.params["arms"] == ["left", "right"]
        assert spec.names[:7] == ("left.dx", "left.dy", "left.dz", "left.droll", "left.dpitch", "left.dyaw", "left.gripper")
        assert spec.names[7] == "right.dx" and len(spec.names) == 14
        ep, src = converted.read_episode(0), source.read_episode(0)
        assert ep["action"].shape == (len(src["action"]), 14) and ep["info.ee_anchor"].shape[1] == 14
        # The grippers: gym-aloha's opening (1 open) became ee7's closedness (1 closed).
        np.testing.assert_allclose(ep["action"][:, 6], 1.0 - src["action"][:, 6], atol=1e-6)
        np.testing.assert_array_equal(ep["obs.agent_pos"], src["obs.agent_pos"])  # every other feature kept
        assert converted.episode_info(0)["seed"] == source.episode_info(0)["seed"]


def test_a_policy_of_each_arm_s_ee7_is_not_run_as_joint_targets(scene_store: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    out, run = tmp_path / "ee7.zarr", tmp_path / "run"
    assert main(["convert", str(scene_store), "--to", "ee7", "--robot", ARMS, "--out", str(out)]) == 0
    assert main(["train", str(out), "--steps", "3", "--batch-size", "8", "--out", str(run)]) == 0
    capsys.readouterr()
    assert main(["eval", str(run), "--episodes", "1"]) != 0
    err = capsys.readouterr().err
    assert "each arm's ee7 (left, right)" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_what_ee7_per_arm_cannot_convert_is_one_line(scene_store: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    pick = tmp_path / "pick.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "1", "--workers", "0", "--out", str(pick)]) == 0
    capsys.readouterr()
    for argv, needle in [
        ([str(scene_store), "--to", "ee_abs", "--check"], "has several arms: it converts --to ee7"),
        ([str(pick), "--to", "ee7", "--check"], "ee7 for each arm converts a Gymnasium environment's joint targets"),
    ]:
        out = tmp_path / "x.zarr"
        assert main(["convert", *argv, "--robot", ARMS, "--out", str(out)]) != 0
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
