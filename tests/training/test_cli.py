"""`demo train` and `demo bench train` from the command line: tables, JSON, one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from demo.bench.load import build_store
from demo.cli.main import main


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "data.zarr"
    build_store(path, frames=1000, episode_length=50, obs_dim=5, seed=0).close()
    return path


def test_train_writes_a_run_and_json(data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, js = tmp_path / "run", tmp_path / "train.json"
    rc = main(["train", str(data), "--out", str(out), "--steps", "30", "--batch-size", "16", "--chunk", "4",
               "--policy-opt", "hidden=16,16", "--include-failures", "--json", str(js)])
    assert rc == 0
    summary = json.loads(js.read_text())
    assert summary["step"] == 30 and summary["expert_labels"] == 1000
    run = json.loads((out / "run.json").read_text())
    assert run["command"].startswith("demo train ")
    assert run["policy"]["config"]["hidden"] == [16, 16]
    assert run["policy"]["execution"] == {"execute": 1, "ensemble": 0.01}  # chunking defaults to ACT's ensembling
    assert "trained" in capsys.readouterr().out
    # Continue it to more steps.
    assert main(["train", str(data), "--out", str(out), "--steps", "40", "--batch-size", "16", "--chunk", "4",
                 "--policy-opt", "hidden=16,16", "--include-failures", "--resume", "--json", str(js)]) == 0
    assert json.loads(js.read_text())["step"] == 40


@pytest.mark.parametrize(
    "args, message",
    [
        (["--algo", "gail"], "unknown algorithm 'gail'"),
        (["--policy-opt", "hidden"], "is not KEY=VALUE"),
        (["--policy-opt", "depth=3"], "has no option 'depth'"),
        (["--chunk", "2", "--execute", "4"], "cannot exceed --chunk"),
    ],
)
def test_bad_flags_are_one_line_errors(data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str],
                                       message: str) -> None:
    rc = main(["train", str(data), "--out", str(tmp_path / "run"), "--steps", "5", *args])
    err = capsys.readouterr().err
    assert rc == 1 and message in err and "Traceback" not in err


def test_missing_store_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["train", str(tmp_path / "nope.zarr"), "--out", str(tmp_path / "run")])
    assert rc == 1 and "no such store" in capsys.readouterr().err


def test_bench_train_json(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    rc = main(["bench", "train", "--json", str(out), "--frames", "20000", "--seconds", "0.6", "--hidden", "64,64"])
    assert rc == 0
    result = json.loads(out.read_text())
    assert result["samples_per_s"] > 0 and result["reference_samples_per_s"] > 0
    assert result["ratio_to_reference"] == pytest.approx(result["samples_per_s"] / result["reference_samples_per_s"])
    assert result["model"]["hidden"] == [64, 64] and "bare forward + backward" in result["reference"]
