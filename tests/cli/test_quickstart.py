"""`demo quickstart`: every stage runs and leaves its artefacts (a tiny configuration)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.store import EpisodeStore

pytestmark = pytest.mark.slow  # every stage end to end: ~6 s


def test_quickstart_runs_every_stage(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "qs"
    argv = ["quickstart", "--out", str(out), "--task", "reach", "--episodes", "6", "--poor", "3", "--steps", "50",
            "--eval-episodes", "2", "--workers", "1"]
    assert main(argv) == 0
    results = json.loads((out / "quickstart.json").read_text())
    assert set(results) >= {"collect", "curate", "convert", "train", "eval"}
    demos = EpisodeStore.open(out / "demos.zarr")
    assert demos.num_episodes == 9 and set(demos.column("operator")) == {"expert", "poor"}
    assert EpisodeStore.open(out / "curated.zarr").num_episodes == results["curate"]["kept"]
    assert EpisodeStore.open(out / "curated_ee7.zarr").meta.action.name == "ee7"
    assert results["convert"]["round_trip_max_pos_err_m"] < 1e-4
    assert results["eval"]["episodes"] == 2
    assert main(argv) == 1  # the run directory exists: refuse to clobber it
    assert "already exists" in capsys.readouterr().err
