"""The CLI's progress renderer: ticks become bars on stderr (stdout stays for JSON), nothing at all
before the first bar (so a command that fails validation prints only its error)."""

from __future__ import annotations

import pytest

from demo.cli.progress import bars, format_fields
from demo.progress import Tick


def test_bars_draw_on_stderr_with_fields_and_messages(capsys: pytest.CaptureFixture[str]) -> None:
    with bars() as progress:
        progress(Tick("collect reach", 0, 3))
        progress(Tick("collect reach", 3, 3, {"success": "3/3", "frames/s": 1234.5678}))
        progress(Tick("train bc", 5, None, {"loss": 0.000123456}))
        progress(Tick("train bc", message="round 1: 40 labels"))
    out, err = capsys.readouterr()
    assert out == ""
    assert "collect reach" in err and "3/3" in err and "success 3/3  frames/s 1235" in err
    assert "train bc" in err and "5/?" in err and "loss 0.0001235" in err
    assert "round 1: 40 labels" in err and err.endswith("\n")


def test_no_bar_no_output(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError):
        with bars():
            raise ValueError("bad input")  # validation failed before any tick
    with bars(enabled=False) as progress:
        progress(Tick("collect reach", 1, 2, message="hidden"))
    assert capsys.readouterr() == ("", "")


def test_format_fields() -> None:
    assert format_fields({"success": "2/4", "loss": 0.123456, "step": 7}) == "success 2/4  loss 0.1235  step 7"


def test_bars_are_cleared_on_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError):
        with bars() as progress:
            progress(Tick("import lerobot", 3, 7))
            raise ValueError("episode 4 is corrupted")
    assert capsys.readouterr() == ("", "")  # not a terminal: nothing drawn; a terminal clears the bar


def test_off_a_terminal_a_stage_is_a_whole_line_now_and_then(capsys: pytest.CaptureFixture[str]) -> None:
    """A log file gets plain lines, never a bar cut to 80 columns: with ``log_every_s=0`` one per tick, each
    with the counts, the elapsed time, an estimate of the time left and every field; at the end one more per stage
    whose last line is out of date, none repeating it."""
    fields = {"loss": 0.5, "val": 0.25, "success": "-", "samples/s": 259.0, "info": "x" * 100}
    with bars(log_every_s=0.0) as progress:
        progress(Tick("train dagger", 1, 4, fields))
        progress(Tick("train dagger", 2, 4, fields))
        progress(Tick("evaluate", 1, 2))
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 3  # one per tick while it ran, none at the end: each stage's last line is current
    assert lines[0].startswith("train dagger  1/4  0:00:00  eta 0:00:00  loss 0.5  val 0.25  success -")
    assert lines[1].startswith("train dagger  2/4") and lines[0].endswith("x" * 100)
    assert lines[2] == "evaluate  1/2  0:00:00  eta 0:00:00"
    with bars() as progress:  # the default: a minute between lines, so a short stage is one line, at the end
        progress(Tick("collect pick", 1, 2))
        progress(Tick("collect pick", 2, 2, message="episode 2 ok"))
    assert capsys.readouterr().err.splitlines() == ["episode 2 ok", "collect pick  2/2  0:00:00"]


def test_off_a_terminal_a_finished_stage_keeps_its_time(capsys: pytest.CaptureFixture[str],
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A stage that finished before the command ended reports the time it took, not the command's: its clock
    stops when done reaches total (a collection's line, printed after the store was written)."""
    clock = iter([0.0, 90.0, 200.0])  # the stage's first tick, its last (90 s later), the command's end
    monkeypatch.setattr("demo.cli.progress.time.monotonic", lambda: next(clock))
    with bars() as progress:
        progress(Tick("collect pick", 1, 2))
        progress(Tick("collect pick", 2, 2))
    assert capsys.readouterr().err.splitlines() == ["collect pick  2/2  0:01:30"]
