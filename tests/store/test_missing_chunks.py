"""Damaged data is refused where it is read, naming the episode: a deleted chunk file by every command that
reads frames (zarr would read it as zeros, which downstream commands would store with fresh, valid
checksums), a changed byte by every command that reads whole episodes."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.store import EpisodeStore
from demo.verify import NO_VERIFY_ENV


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


def test_a_flipped_byte_is_refused_by_whole_episode_readers(tmp_path: Path, one_line_error) -> None:
    """Uncompressed chunks have no codec checksum: the episode's own CRC-32 catches a changed byte."""
    path = tmp_path / "s.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "6", "--seed", "0", "--out", str(path)]) == 0
    with EpisodeStore.open(path) as store:
        start = int(store.column("start")[3])
    chunk = path / "data" / "action" / "c" / "0" / "0"
    raw = bytearray(chunk.read_bytes())
    raw[start * 8 * 4 + 5] ^= 0x10  # a bit of episode 3's first action (8 float32 a frame)
    chunk.write_bytes(bytes(raw))
    for argv in (["convert", str(path), "--to", "ee7", "--out", str(tmp_path / "e.zarr")],
                 ["export", str(path), "--format", "lerobot", "--out", str(tmp_path / "l")]):
        one_line_error(argv, "episode 3: its data does not match its checksum")
    one_line_error(["info", str(path), "--check"], "1 damaged episode(s); first: episode 3")
    assert not (tmp_path / "e.zarr").exists() and not (tmp_path / "l").exists()


def test_no_verify_reads_damage_for_a_user_who_knows(damaged: Path, tmp_path: Path, one_line_error) -> None:
    """``demo --no-verify``: the missing chunk reads as zeros and a changed byte as it is, for that command
    alone; ``info --check`` still checks."""
    assert main(["--no-verify", "curate", str(damaged), "--out", str(tmp_path / "c.zarr")]) == 0
    assert NO_VERIFY_ENV not in os.environ  # one command's setting, not the process's
    with EpisodeStore.open(tmp_path / "c.zarr") as curated:
        assert curated.num_episodes > 0
    one_line_error(["curate", str(damaged), "--out", str(tmp_path / "c2.zarr")], "is missing")  # checks again
    one_line_error(["--no-verify", "info", str(damaged), "--check"], "damaged episode")
