"""Staged output: nothing half-written, nothing clobbered; exact restoration of per-episode columns."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest

from demo.errors import DemoError
from demo.interop.common import camera_name, restore_columns, staged_output
from demo.interop.sample import make_sample_store, sample_meta
from demo.store import EpisodeStore


def looks_like_ours(p: Path) -> bool:
    return (p / "ours").exists()


def test_staged_output_replaces_only_on_success(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with staged_output(out, overwrite=False, looks_like=looks_like_ours, kind="thing", is_dir=True) as tmp:
        assert tmp != out and not out.exists()
        (tmp / "ours").write_text("1")
    assert (out / "ours").read_text() == "1"
    with pytest.raises(RuntimeError):
        with staged_output(out, overwrite=True, looks_like=looks_like_ours, kind="thing", is_dir=True) as tmp:
            (tmp / "ours").write_text("2")
            raise RuntimeError("crash mid-write")
    assert (out / "ours").read_text() == "1"  # the failed write left the old output alone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # and no temporary behind
    with pytest.raises(DemoError, match="already exists"):
        with staged_output(out, overwrite=False, looks_like=looks_like_ours, kind="thing", is_dir=True):
            pass
    with staged_output(out, overwrite=True, looks_like=looks_like_ours, kind="thing", is_dir=True) as tmp:
        (tmp / "ours").write_text("3")
    assert (out / "ours").read_text() == "3"
    other = tmp_path / "other"
    other.mkdir()
    (other / "x").write_text("keep")
    with pytest.raises(DemoError, match="is not a thing"):
        with staged_output(other, overwrite=True, looks_like=looks_like_ours, kind="thing", is_dir=True):
            pass
    assert (other / "x").read_text() == "keep"


def test_restore_columns_keeps_arrow_types_and_nulls(tmp_path: Path) -> None:
    src = EpisodeStore.open(make_sample_store(tmp_path / "a.zarr", episodes=4))
    with EpisodeStore.create(tmp_path / "b.zarr", sample_meta()) as dst:
        for i in range(4):
            info = src.episode_info(i)
            dst.append_episode(src.read_episode(i), **{k: info[k] for k in ("success", "seed", "source", "operator", "task")})
        extras = [n for n in src.table.column_names if n not in dst.table.column_names]
        restore_columns(dst, [(n, src.table.column(n).combine_chunks()) for n in extras])
        assert dst.table.equals(src.table)
        assert dst.table.schema.field("count32").type == pa.int32()
        assert dst.table.column("note").null_count == 2


def test_camera_name() -> None:
    assert camera_name("obs.image_front") == "front"
    assert camera_name("obs.wrist") == "wrist"
    assert camera_name("obs.image_") == "image_"


def test_track_reports_each_item_done() -> None:
    from demo.interop.common import track
    from demo.progress import Tick

    ticks: list[Tick] = []
    assert list(track("abc", 3, "export lerobot", ticks.append)) == ["a", "b", "c"]
    assert [(t.stage, t.done, t.total) for t in ticks] == [("export lerobot", i, 3) for i in range(4)]
    assert list(track("ab", 2, "import", None)) == ["a", "b"]  # no callback: silent
