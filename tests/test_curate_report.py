"""The report: per-operator keep rates, precision/recall, the JSON, the PNG, and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.curate import report, synthetic
from demo.curate.curate import analyse
from demo.store import EpisodeStore


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    episodes = synthetic.mixed_episodes(24, seed=5)
    episodes[1][1]["success"] = False
    return synthetic.write_store(tmp_path_factory.mktemp("r") / "mixed.zarr", episodes)


def test_operator_rows_and_detection(mixed: Path) -> None:
    with EpisodeStore.open(mixed) as store:
        c = analyse(store)
    rows = {r["operator"]: r for r in report.operator_rows(c)}
    assert set(rows) == {"expert", "good", "okay", "poor", "<failed>"}
    for name in ("expert", "good", "okay", "poor"):
        r = rows[name]
        assert r["episodes"] == 6
        assert r["kept_share"] + r["dropped_share"] == pytest.approx(1.0)
        assert r["kept"] == int(c.kept[np.asarray(c.table.column("operator").to_pylist()) == name].sum())
    assert rows["<failed>"]["episodes"] == 1 and rows["<failed>"]["dropped_share"] == 1.0
    assert rows["good"]["dropped_for"].get("failed") == 1
    t = report.targets(list(rows.values()))
    assert t is not None and t["met"] == all(v >= 0.9 for k, v in t.items() if k.endswith("share"))
    d = report.detection(c)
    assert d["bad_episodes"] == 7  # six poor + one failed good
    assert 0.0 <= d["precision"] <= 1.0 and d["recall"] >= 0.9


def test_cli_writes_store_json_and_png(mixed: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out, rep, png = tmp_path / "out.zarr", tmp_path / "report.json", tmp_path / "signals.png"
    rc = main(["curate", str(mixed), "--out", str(out), "--report", str(rep), "--plot", str(png), "--show", "all"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "per operator" in text and "targets" in text and "dropped" in text
    r = json.loads(rep.read_text())
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
    assert main(["curate", str(copy), "--mask", "good", "--report", "-", "--max-jerk", "off"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["thresholds"]["max_jerk"] is None and r["mask"] == "good"
    with EpisodeStore.open(copy) as store:
        assert int(store.mask("good").sum()) == r["summary"]["kept"]


def one_line_error(capsys: pytest.CaptureFixture, argv: list[str], needle: str) -> None:
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc != 0
    assert len(err.splitlines()) == 1, err
    assert needle in err and "Traceback" not in err, err


def test_cli_bad_input(mixed: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    one_line_error(capsys, ["curate", str(tmp_path / "nope.zarr")], "no such store")
    one_line_error(capsys, ["curate", str(mixed), "--max-jerk", "lots"], "--max-jerk: expected a number or 'off'")
    one_line_error(capsys, ["curate", str(mixed), "--out", str(mixed)], "is the source store")
    one_line_error(capsys, ["curate", str(mixed), "--min-consistency", "2"], "must be a fraction")
    (tmp_path / "junk").mkdir()
    one_line_error(capsys, ["curate", str(tmp_path / "junk")], "not a demo episode store")
