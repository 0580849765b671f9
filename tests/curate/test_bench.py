"""`demo bench curate` on a small store: the figure, its same-run reference and the kept shares."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from demo.bench.curate import run
from demo.cli.main import main

pytestmark = pytest.mark.slow  # the curate benchmark twice: ~14 s


def test_bench_small_store(tmp_path: Path) -> None:
    r = run(frames=20_000, episode_s=5.0, repeats=1, workdir=tmp_path)
    assert 15_000 <= r["frames"] <= 25_000 and r["episodes"] > 100
    assert r["frames_per_s"] == pytest.approx(r["frames"] / r["seconds"])
    assert r["reference_seconds"] > 0 and r["ratio_to_reference"] == pytest.approx(r["frames_per_s"] / r["reference_frames_per_s"])
    assert set(r["stage_seconds"]) >= {"load", "idle", "jerk", "consistency", "duplicates", "decide"}
    assert r["cores"] == 1
    # The synthetic operators are told apart: experts kept, poor ones dropped.
    assert r["kept_share_by_operator"]["expert"] >= 0.9 and r["kept_share_by_operator"]["poor"] <= 0.1
    assert not list(tmp_path.iterdir())  # the temporary store is removed


def test_bench_cli_json(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "curate", "--frames", "8000", "--episode-s", "3", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["benchmark"] == "curate" and r["target_seconds_per_1m"] == 20.0
    assert isinstance(r["meets_target"], bool)
