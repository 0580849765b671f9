"""RowWriter writes the chunk files zarr would, reads back through zarr, and survives torn tails."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr

from demo.store.chunk_writer import RowWriter


def _pair(tmp_path: Path, compressors, shape=(40, 3), chunks=(16, 3), dtype="float32"):
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w")
    mine = group.create_array("mine", shape=shape, chunks=chunks, dtype=dtype, compressors=compressors)
    theirs = group.create_array("theirs", shape=shape, chunks=chunks, dtype=dtype, compressors=compressors)
    return mine, theirs, tmp_path / "g.zarr"


@pytest.mark.parametrize("compressors", [None, "auto"], ids=["raw", "zstd"])
def test_appends_match_zarr_byte_for_byte(tmp_path, compressors) -> None:
    mine, theirs, root = _pair(tmp_path, compressors)
    writer = RowWriter.for_array(mine, root / "mine")
    assert writer is not None
    rng = np.random.default_rng(0)
    start = 0
    for n in (5, 11, 1, 16, 7):  # crosses chunk boundaries, fills one chunk exactly, ends mid-chunk
        rows = rng.normal(size=(n, 3)).astype(np.float32)
        writer.write(start, rows)
        theirs[start : start + n] = rows
        start += n
    np.testing.assert_array_equal(mine[:start], theirs[:start])
    files = sorted(p.relative_to(root / "theirs") for p in (root / "theirs" / "c").rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(root / "mine") for p in (root / "mine" / "c").rglob("*") if p.is_file())
    for f in files:
        assert (root / "mine" / f).read_bytes() == (root / "theirs" / f).read_bytes(), f


def test_a_fresh_writer_continues_a_chunk_another_one_started(tmp_path) -> None:
    """A store reopened for appending continues the tail chunk written by the last session."""
    mine, _, root = _pair(tmp_path, "auto")
    a = np.arange(30, dtype=np.float32).reshape(10, 3)
    RowWriter.for_array(mine, root / "mine").write(0, a[:4])
    RowWriter.for_array(mine, root / "mine").write(4, a[4:])
    np.testing.assert_array_equal(mine[:10], a)


@pytest.mark.parametrize("compressors", [None, "auto"], ids=["raw", "zstd"])
def test_a_torn_uncommitted_chunk_is_rewritten_whole(tmp_path, compressors) -> None:
    """A crash while creating a chunk leaves it short or undecodable; it held no committed rows."""
    mine, _, root = _pair(tmp_path, compressors)
    writer = RowWriter.for_array(mine, root / "mine")
    committed = np.ones((16, 3), np.float32)
    writer.write(0, committed)  # chunk 0, complete
    torn = root / "mine" / "c" / "1" / "0"
    torn.parent.mkdir(parents=True, exist_ok=True)
    torn.write_bytes(b"\x01\x02\x03")  # a crash mid-way through creating chunk 1
    rows = np.full((4, 3), 7.0, np.float32)
    RowWriter.for_array(mine, root / "mine").write(16, rows)
    np.testing.assert_array_equal(mine[:16], committed)
    np.testing.assert_array_equal(mine[16:20], rows)
    np.testing.assert_array_equal(mine[20:32], 0.0)


def test_raw_appends_leave_committed_bytes_untouched(tmp_path) -> None:
    """Uncompressed appends write only the new rows' bytes: the file's prefix is never rewritten."""
    mine, _, root = _pair(tmp_path, None)
    writer = RowWriter.for_array(mine, root / "mine")
    writer.write(0, np.full((3, 3), 2.0, np.float32))
    chunk = root / "mine" / "c" / "0" / "0"
    before = chunk.read_bytes()[: 3 * 12]
    writer.write(3, np.full((5, 3), 9.0, np.float32))
    assert chunk.read_bytes()[: 3 * 12] == before
    assert len(chunk.read_bytes()) == 16 * 12


def test_other_layouts_are_left_to_zarr(tmp_path) -> None:
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w")
    split_columns = group.create_array("a", shape=(10, 4), chunks=(5, 2), dtype="float32", compressors=None)
    blosc = group.create_array("b", shape=(10, 4), chunks=(5, 4), dtype="float32",
                               compressors=zarr.codecs.BloscCodec())
    assert RowWriter.for_array(split_columns, tmp_path / "g.zarr" / "a") is None
    assert RowWriter.for_array(blosc, tmp_path / "g.zarr" / "b") is None
