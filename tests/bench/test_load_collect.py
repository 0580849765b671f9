"""`demo bench load` and `demo bench collect` on small sizes: figure and reference from one run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from demo.cli.main import main


def test_bench_load_small(tmp_path: Path) -> None:
    from demo.bench.load import run

    r = run(frames=20_000, episode_length=100, seconds=0.3, workdir=tmp_path)
    assert r["frames"] == 20_000 and r["episodes"] == 200
    assert r["samples_per_s"] > 0 and r["reference_samples_per_s"] > 0
    assert r["ratio_to_reference"] == pytest.approx(r["samples_per_s"] / r["reference_samples_per_s"])


@pytest.mark.slow
def test_bench_collect_cli_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "collect.json"
    assert main(["bench", "collect", "--task", "reach", "--episodes", "4", "--seconds", "0.2", "--rounds", "1",
                 "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    for key in ("single_process", "one_worker", "two_workers"):
        assert r[key]["frames"] > 0 and r[key]["success_rate"] == 1.0
    physics = r["reference_physics"]["control_steps_per_s"]
    assert r["ratio_to_physics"] == pytest.approx(r["one_worker"]["frames_per_s"] / physics)
    assert len(r["samples"]["physics"]) == 2 and len(r["samples"]["one_worker"]) == 1
