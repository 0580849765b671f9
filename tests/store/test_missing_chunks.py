"""A deleted chunk file is refused where it is read, naming the episode, by every command that reads frames
(zarr would read it as zeros, which downstream commands would store with fresh, valid checksums)."""

from __future__ import annotations

from pathlib import Path

import pytest

from demo.cli.main import main
from demo.store import EpisodeStore


@pytest.fixture(scope="module")
def damaged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A reach store of two action chunks (2,048 frames each) whose second chunk file was deleted."""
    path = tmp_path_factory.mktemp("missing") / "ref.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "90", "--seed", "0", "--workers", "2",
                 "--out", str(path)]) == 0
    chunk = path / "data" / "action" / "c" / "1" / "0"
    assert chunk.is_file(), "the store should span two action chunks"
    chunk.unlink()
    return path


def test_every_reader_refuses_a_missing_chunk(damaged: Path, tmp_path: Path, one_line_error) -> None:
    with EpisodeStore.open(damaged) as store:
        ends = store.episode_ends
        first_damaged = int((ends <= 2048).sum())  # the episode holding frame 2048
        store.read_episode(0)  # an episode in the intact chunk still reads
    needles = ("action/c/1/0", "is missing", f"episode {first_damaged}")
    one_line_error(["curate", str(damaged), "--out", str(tmp_path / "c.zarr")], *needles)
    one_line_error(["convert", str(damaged), "--to", "ee7", "--out", str(tmp_path / "e.zarr")], *needles)
    one_line_error(["export", str(damaged), "--format", "lerobot", "--out", str(tmp_path / "l")], *needles)
    one_line_error(["train", str(damaged), "--steps", "5", "--out", str(tmp_path / "run")], *needles)
    one_line_error(["info", str(damaged), "--check"], "damaged episode")
    for written in ("c.zarr", "e.zarr", "l", "run"):
        assert not (tmp_path / written).exists(), written  # nothing half-written
