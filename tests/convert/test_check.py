"""`demo convert --check`: original and converted actions replayed from the recorded states."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.convert.check import replay_check
from demo.convert.convert import ConvertOptions
from demo.errors import DemoError
from demo.store import EpisodeStore

pytestmark = pytest.mark.slow  # collects and replays pick episodes: ~8 s


@pytest.fixture(scope="module")
def pick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.collect.scripted import CollectConfig, collect_scripted

    out = tmp_path_factory.mktemp("check") / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=3, seed=1), out)
    return out


def test_ee7_replay_succeeds_where_the_original_does(pick: Path):
    report = replay_check(pick, ConvertOptions(to="ee7"))
    s = report.summary()
    assert s["episodes"] == 3 and s["original_successes"] >= 2
    assert s["converted_success_given_original"] == 1.0
    for e in report.episodes:
        assert e.original_success == e.recorded_success  # replaying the labels reproduces the recording
        assert e.max_pos_err_m < 5e-3 and e.max_rot_err_rad < 2e-2  # null-space IK differences only
        assert e.ik_failed_steps == 0
    # ee_abs with Euler angles through the same adapter.
    report = replay_check(pick, ConvertOptions(to="ee_abs", rotation="euler"), episodes=[0])
    assert report.episodes[0].converted_success == report.episodes[0].original_success


def test_check_cli_table_and_json(pick: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    path = tmp_path / "check.json"
    assert main(["convert", str(pick), "--to", "ee7", "--check", "--episodes", "1", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "replay: joint_pos vs ee7" in out and "converted succeed on 1/1 episodes" in out
    report = json.loads(path.read_text())["check"]
    assert len(report["episodes"]) == 1 and report["summary"]["episodes"] == 1
    assert report["episodes"][0]["agree"] is True


def test_check_needs_recorded_states(pick: Path, tmp_path: Path):
    with EpisodeStore.open(pick) as store:
        meta = type(store.meta).from_json(store.meta.to_json())
        del meta.features["sim.state"]
        data = [store.read_episode(0)]
        with EpisodeStore.create(tmp_path / "nostate.zarr", meta) as out:
            out.append_episode({k: v for k, v in data[0].items() if k != "sim.state"}, success=True)
    with pytest.raises(DemoError, match="has no sim.state"):
        replay_check(tmp_path / "nostate.zarr", ConvertOptions(to="ee7"))
