"""A ``train_state.pt`` that cannot be resumed from is reported as what is wrong with it (empty,
truncated, not a torch checkpoint at all), not as a pickle; real pickles are still refused as such."""

from __future__ import annotations

import hashlib
import os
import pickle
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.policies.checkpoint import STATE_FILE, load_train_state


class Bomb:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory, synthetic_store, torch_one_thread) -> Path:
    root = tmp_path_factory.mktemp("state")
    store = synthetic_store(root / "s.zarr", episodes=6, length=20)
    assert main(["train", str(store), "--out", str(root / "run"), "--steps", "2", "--batch-size", "8", "--warmup", "1",
                 "--chunk", "1", "--no-ensemble", "--policy-opt", "hidden=8"]) == 0
    return root / "run"


def with_state(run: Path, tmp_path: Path, data: bytes) -> Path:
    copy = tmp_path / "run"
    copy.mkdir()
    for f in run.iterdir():
        if f.is_file():
            (copy / f.name).write_bytes(f.read_bytes())
    (copy / STATE_FILE).write_bytes(data)
    return copy


@pytest.mark.parametrize("make,expected", [
    # The case: random bytes were reported as "Python objects ... a pickle can run code".
    (lambda good: os.urandom(4096).replace(b"PK", b"pk").replace(b"\x80", b"\x81"),
     "not a torch checkpoint: neither a zip archive nor a pickle"),
    (lambda good: good[: len(good) // 2], "truncated or corrupted"),
    (lambda good: b"", "empty file (0 bytes)"),
    (lambda good: pickle.dumps({"step": Bomb()}), "refusing to load: a plain Python pickle"),
])
def test_state_problem_is_named(make, expected: str, run: Path, tmp_path: Path) -> None:
    copy = with_state(run, tmp_path, make((run / STATE_FILE).read_bytes()))
    with pytest.raises(DemoError) as err:
        load_train_state(copy)
    assert err.value.where == str(copy / STATE_FILE) and err.value.problem.startswith(expected), err.value.problem
    assert ("pickle can run code" in err.value.problem) == expected.startswith("refusing")


def test_torch_pickle_of_objects_is_refused_naming_them(run: Path, tmp_path: Path) -> None:
    import io

    import torch

    buf = io.BytesIO()
    torch.save({"step": 1, "x": Bomb()}, buf)
    copy = with_state(run, tmp_path, buf.getvalue())
    with pytest.raises(DemoError, match=r"refusing to load: it holds Python objects \(posix.system\).*pickle can run code"):
        load_train_state(copy)


def test_resume_from_random_bytes_is_one_line_and_writes_nothing(run: Path, tmp_path: Path, capsys) -> None:
    copy = with_state(run, tmp_path, os.urandom(2048).replace(b"PK", b"pk").replace(b"\x80", b"\x81"))
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in copy.iterdir()}
    capsys.readouterr()
    store = run.parent / "s.zarr"
    assert main(["train", str(store), "--out", str(copy), "--resume", "--steps", "4", "--batch-size", "8", "--warmup", "1",
                 "--chunk", "1", "--no-ensemble", "--policy-opt", "hidden=8"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {copy / STATE_FILE}: not a torch checkpoint") and err.count("\n") == 1, err
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in copy.iterdir()} == before
