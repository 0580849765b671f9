"""`demo bench render` in miniature: it runs the real collection and the bare-render reference and
writes both, their ratio and the stored bytes per frame as JSON (no timing is asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from demo.cli.main import main

TINY = ["--task", "reach", "--episodes", "2", "--seconds", "0.05", "--rounds", "1", "--camera", "front@16x16",
        "--camera", "wrist@16x8"]


@pytest.mark.slow
def test_bench_render_writes_figure_reference_and_ratio(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "render.json"
    assert main(["bench", "render", *TINY, "--json", str(out)]) == 0
    assert "bench render" in capsys.readouterr().out  # the table goes to stdout when the JSON goes to a file
    r = json.loads(out.read_text())
    assert r["cameras"] == ["front@16x16", "wrist@16x8"] and r["workers"] == 1  # as `demo collect`
    assert r["figure"]["frames_per_s"] > 0 and r["figure"]["episodes"] == 2
    assert r["reference"]["frames_per_s"] > 0 and r["reference"]["frames"] > 0
    assert r["ratio"] == pytest.approx(r["figure"]["frames_per_s"] / r["reference"]["frames_per_s"])
    assert r["cpu_ratio"] is None  # a worker's CPU time is not this process's
    assert len(r["samples"]["reference"]) == 2 and len(r["samples"]["collection"]) == 1  # + the closing reference
    sizes = r["camera_bytes"]
    assert sizes["per_camera"]["obs.image_wrist"]["raw_bytes_per_frame"] == 8 * 16 * 3
    assert sizes["total"]["raw_bytes_per_frame"] == (16 + 8) * 16 * 3 and sizes["total"]["compression_ratio"] > 1


@pytest.mark.parametrize(
    "args,needle",
    [(["--episodes", "1"], "--episodes: must be at least 2"), (["--camera", "front"], "NAME@WIDTHxHEIGHT")],
)
def test_bad_settings_fail_in_one_line(args: list[str], needle: str, capsys: pytest.CaptureFixture) -> None:
    assert main(["bench", "render", "--task", "reach", *args]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err
