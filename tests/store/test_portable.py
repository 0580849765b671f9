"""A store (and a run) collected with a robot config from a temporary folder keeps working after it
is moved and that folder is deleted: the store carries the robot's files (MJCF, includes, meshes).
When those files are missing or changed, every command fails with one line naming the file."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.sim.robot import ASSETS
from demo.store import EpisodeStore
from demo.store.robot_files import ROBOT_DIR, file_table, sha256_file

TETRA = "v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def make_robot(folder: Path) -> Path:
    """The built-in arm's config and MJCF in ``folder``, the MJCF in a subfolder, plus an include that
    points at a mesh folder beside it (``../meshes``): the layout a store must reproduce."""
    (folder / "xml").mkdir(parents=True)
    (folder / "meshes").mkdir()
    toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', 'mjcf = "xml/panda.xml"')
    (folder / "arm.toml").write_text(toml)
    xml = (ASSETS / "panda.xml").read_text()
    head = xml.index(">", xml.index("<mujoco")) + 1
    (folder / "xml" / "panda.xml").write_text(xml[:head] + '\n  <include file="extra.xml"/>' + xml[head:])
    (folder / "xml" / "extra.xml").write_text(
        '<mujoco><compiler meshdir="../meshes"/><asset><mesh name="probe" file="tetra.obj"/></asset></mujoco>')
    (folder / "meshes" / "tetra.obj").write_text(TETRA)
    return folder / "arm.toml"


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(args)
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.fixture(scope="module")
def moved(tmp_path_factory: pytest.TempPathFactory, torch_one_thread: None) -> dict[str, Path]:
    """A 3-episode reach store collected with a temporary robot, moved elsewhere, the robot deleted."""
    from demo.collect.scripted import CollectConfig, collect_scripted

    tmp = tmp_path_factory.mktemp("portable")
    config = make_robot(tmp / "robot_folder")
    collect_scripted(CollectConfig(task="reach", episodes=3, seed=0, robot=str(config)), tmp / "first" / "s.zarr",
                     workers=0)
    (tmp / "elsewhere").mkdir()
    store = Path(shutil.move(tmp / "first" / "s.zarr", tmp / "elsewhere" / "s.zarr"))
    shutil.rmtree(tmp / "robot_folder")
    return {"tmp": tmp, "store": store}


def test_the_store_records_its_robot_by_content(moved: dict[str, Path]) -> None:
    with EpisodeStore.open(moved["store"]) as store:
        record = store.meta.robot
    files = file_table(record, "test")
    assert set(files) == {"xml/panda.xml", "xml/extra.xml", "meshes/tetra.obj"}
    assert record["toml"]["mjcf"] == "xml/panda.xml" and record["name"] == "panda_prim"
    for name, digest in files.items():
        assert sha256_file(moved["store"] / ROBOT_DIR / name) == digest


def test_a_moved_store_and_run_work_without_the_robot_folder(
    moved: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from demo.view.app import load_scene_model

    store, tmp = moved["store"], moved["tmp"]
    rc, out, err = run_cli(["info", str(store), "--check", "--json", "-"], capsys)
    assert rc == 0, err
    status = json.loads(out)["robot_status"]
    assert status["ok"] and "files stored with it, 3 files, sha256 verified" in status["detail"]

    rc, _, err = run_cli(["convert", str(store), "--to", "ee7", "--out", str(tmp / "ee7.zarr")], capsys)
    assert rc == 0, err
    assert (tmp / "ee7.zarr" / ROBOT_DIR / "meshes" / "tetra.obj").read_text() == TETRA  # the copy carries it on

    with EpisodeStore.open(store) as opened:
        model, env, description = load_scene_model(opened.meta, where=store)
    assert model is not None, description
    assert model.nmesh == 1 and "reach" in description  # the stored include and mesh were loaded
    env.close()

    run = tmp / "run"
    rc, _, err = run_cli(["train", str(store), "--algo", "bc", "--steps", "20", "--out", str(run)], capsys)
    assert rc == 0, err
    moved_run = Path(shutil.move(run, tmp / "elsewhere" / "run"))
    rc, out, err = run_cli(["eval", str(moved_run), "--episodes", "2", "--json", "-"], capsys)
    assert rc == 0, err
    assert json.loads(out)["episodes"] == 2


def test_missing_or_changed_robot_files_fail_with_one_line(
    moved: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], one_line_error
) -> None:
    from demo.view.app import load_scene_model

    broken = Path(shutil.copytree(moved["store"], tmp_path / "broken.zarr"))
    (broken / ROBOT_DIR / "meshes" / "tetra.obj").unlink()
    missing = str(broken / ROBOT_DIR / "meshes" / "tetra.obj")

    rc, out, _ = run_cli(["info", str(broken), "--json", "-"], capsys)
    status = json.loads(out)["robot_status"]  # info still shows the store, and says what is wrong
    assert rc == 0 and not status["ok"] and missing in status["detail"]
    one_line_error(["info", str(broken), "--check"], missing, "--robot", rc=1)
    one_line_error(["convert", str(broken), "--to", "ee7", "--out", str(tmp_path / "x.zarr")], missing, "--robot", rc=1)
    assert not (tmp_path / "x.zarr").exists()
    with EpisodeStore.open(broken) as opened:
        model, _, note = load_scene_model(opened.meta, where=broken)
    assert model is None and missing in note
    one_line_error(["train", str(broken), "--algo", "bc", "--steps", "5", "--out", str(tmp_path / "run")],
                   missing, "--robot", rc=1)

    # A changed file is refused too; --robot points at a robot that can be found.
    (broken / ROBOT_DIR / "meshes" / "tetra.obj").write_text(TETRA.replace("0.01", "0.02"))
    one_line_error(["convert", str(broken), "--to", "ee7", "--out", str(tmp_path / "x.zarr")], missing, "sha256", rc=1)
    fixed = make_robot(tmp_path / "again")
    rc, _, err = run_cli(["convert", str(broken), "--to", "ee7", "--out", str(tmp_path / "x.zarr"),
                          "--robot", str(fixed)], capsys)
    assert rc == 0, err


def test_a_run_without_its_robot_files_fails_naming_the_file(
    moved: dict[str, Path], tmp_path: Path, one_line_error
) -> None:
    run = Path(shutil.copytree(moved["tmp"] / "elsewhere" / "run", tmp_path / "run"))
    (run / ROBOT_DIR / "xml" / "panda.xml").unlink()
    one_line_error(["eval", str(run), "--episodes", "1"], str(run / ROBOT_DIR / "xml" / "panda.xml"), "--robot", rc=1)


@pytest.mark.parametrize("name", ["../x.xml", "/etc/passwd", "a/../../b.xml", "a\\b.xml", "./a.xml", ""])
def test_a_record_cannot_name_a_file_outside_its_folder(name: str) -> None:
    with pytest.raises(DemoError, match="robot file name"):
        file_table({"files": {name: "0" * 64}}, "store")


def test_a_stored_mjcf_cannot_reach_outside_the_store(moved: dict[str, Path], tmp_path: Path) -> None:
    from demo.sim.robot_record import resolve_robot

    store = Path(shutil.copytree(moved["store"], tmp_path / "evil.zarr"))
    (tmp_path / "outside.xml").write_text("<mujoco/>")
    extra = store / ROBOT_DIR / "xml" / "extra.xml"
    extra.write_text('<mujoco><include file="../../../outside.xml"/></mujoco>')
    with EpisodeStore.open(store, "a") as opened:  # a forged record: hashes that match the forged file
        record = dict(opened.meta.robot)
        record["files"] = {**record["files"], "xml/extra.xml": sha256_file(extra)}
        opened.update_meta(robot=record)
    with pytest.raises(DemoError, match="outside"):
        resolve_robot(record, where=store)
    # A symlink in the store's robot folder is not followed out of the store either.
    extra.unlink()
    extra.symlink_to(tmp_path / "outside.xml")
    record["files"]["xml/extra.xml"] = sha256_file(tmp_path / "outside.xml")
    record["source"] = None
    with pytest.raises(DemoError, match="symlink"):
        resolve_robot(record, where=store)


def test_the_recorded_source_folder_is_used_only_while_it_holds_the_same_files(
    moved: dict[str, Path], tmp_path: Path
) -> None:
    from demo.sim.robot_record import resolve_robot

    store = Path(shutil.copytree(moved["store"], tmp_path / "s.zarr"))
    shutil.rmtree(store / ROBOT_DIR)
    make_robot(tmp_path / "source")
    with EpisodeStore.open(store) as opened:
        record = {**opened.meta.robot, "source": str(tmp_path / "source")}
    assert resolve_robot(record, where=store).mjcf_path == (tmp_path / "source" / "xml" / "panda.xml").resolve()
    (tmp_path / "source" / "xml" / "extra.xml").write_text("<mujoco/>")
    with pytest.raises(DemoError, match="robot file missing.*does not hold the same files; pass --robot"):
        resolve_robot(record, where=store)
