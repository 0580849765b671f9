"""The report: per-operator keep rates, the JSON, the PNG, the reasons stored with --mask, and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.curate import report, synthetic
from demo.curate.curate import analyse
from demo.store.episode_table import REASONS_COLUMN
from demo.store import EpisodeStore


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    episodes = synthetic.mixed_episodes(24, seed=5)
    episodes[1][1]["success"] = False
    return synthetic.write_store(tmp_path_factory.mktemp("r") / "mixed.zarr", episodes)


def test_operator_rows(mixed: Path) -> None:
    with EpisodeStore.open(mixed) as store:
        c = analyse(store)
    rows = {r["operator"]: r for r in report.operator_rows(c)}
    assert set(rows) == {"expert", "good", "okay", "poor", report.FAILED_ROW}
    for name in ("expert", "good", "okay", "poor"):
        r = rows[name]
        assert r["episodes"] == 6
        assert r["kept_share"] + r["dropped_share"] == pytest.approx(1.0)
        assert r["kept"] == int(c.kept[np.asarray(c.table.column("operator").to_pylist()) == name].sum())
    failed = rows[report.FAILED_ROW]
    assert failed["episodes"] == 1 and failed["dropped_share"] == 1.0
    assert rows["good"]["dropped_for"].get("failed") == 1


@pytest.mark.slow
def test_cli_writes_store_json_and_png(mixed: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out, rep, png = tmp_path / "out.zarr", tmp_path / "report.json", tmp_path / "signals.png"
    rc = main(["curate", str(mixed), "--out", str(out), "--json", str(rep), "--plot", str(png), "--show", "all"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "kept and dropped per operator" in text and "dropped for" in text
    assert not any(word in text for word in ("precision", "recall", "target"))  # a user command, not a benchmark
    r = json.loads(rep.read_text())
    assert "detection" not in r and "targets" not in r
    assert r["summary"]["episodes"] == 24 and len(r["episodes"]) == 24
    assert r["summary"]["kept"] + r["summary"]["dropped"] == 24
    assert r["signals"]["jerk"]["units"] == "range/s^3"
    assert r["thresholds"]["max_jerk"] == 400.0
    with EpisodeStore.open(out) as store:
        assert store.num_episodes == r["summary"]["kept"]
        assert store.num_frames == r["summary"]["frames_out"]
    dropped = [e for e in r["episodes"] if not e["kept"]]
    assert dropped and all(e["reasons"] for e in dropped)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_cli_mask_and_json_to_stdout(mixed: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    copy = tmp_path / "copy.zarr"
    with EpisodeStore.open(mixed) as src:
        src.copy_to(copy).close()
    assert main(["curate", str(copy), "--mask", "good", "--json", "-", "--max-jerk", "off"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["thresholds"]["max_jerk"] is None and r["mask"] == "good"
    with EpisodeStore.open(copy) as store:
        assert int(store.mask("good").sum()) == r["summary"]["kept"]
        reasons = store.column(REASONS_COLUMN).tolist()
    assert reasons == ["; ".join(e["reasons"]) for e in r["episodes"]]
    assert any(reasons) and all(bool(text) != e["kept"] for text, e in zip(reasons, r["episodes"]))


def test_cli_bad_input(mixed: Path, tmp_path: Path, one_line_error) -> None:
    one_line_error(["curate", str(tmp_path / "nope.zarr")], "no such store")
    one_line_error(["curate", str(mixed), "--max-jerk", "lots"], "--max-jerk: expected a number or 'off'")
    one_line_error(["curate", str(mixed), "--out", str(mixed)], "is the source store")
    one_line_error(["curate", str(mixed), "--min-consistency", "2"], "must be a fraction")
    (tmp_path / "junk").mkdir()
    one_line_error(["curate", str(tmp_path / "junk")], "not a demo episode store")


def test_progress_ticks_one_per_step(mixed: Path, tmp_path: Path) -> None:
    from demo.curate.curate import STEPS, curate
    from demo.progress import Tick

    ticks: list[Tick] = []
    c = curate(mixed, tmp_path / "kept.zarr", progress=ticks.append)
    total = len(STEPS) + 1  # and the write
    assert {t.stage for t in ticks} == {"curate"} and {t.total for t in ticks} == {total}
    assert [t.fields.get("step") for t in ticks[: len(STEPS)]] == list(STEPS)
    assert [t.done for t in ticks] == sorted(t.done for t in ticks) and ticks[-1].done == total
    assert ticks[-1].fields["kept"] == f"{int(c.kept.sum())}/{len(c.kept)}"
