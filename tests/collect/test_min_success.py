"""A collection whose expert fails often says so: a warning below 90%, an error below --min-success."""

from __future__ import annotations

from pathlib import Path

import pytest

from demo.cli.main import main
from demo.collect.scripted import SUCCESS_WARNING, CollectResult, check_success
from demo.errors import DemoError
from demo.store import EpisodeStore


def result(successes: int, episodes: int = 10) -> CollectResult:
    return CollectResult("pick.zarr", episodes, successes, frames=100, seconds=1.0, modes={})


def test_check_success_thresholds() -> None:
    assert check_success(result(9)) is None  # 0.9: not below the warning line
    assert check_success(result(10), min_success=1.0) is None
    warning = check_success(result(4))
    assert warning is not None and warning.startswith("pick.zarr: expert success 0.40 (4/10 episodes)")
    assert f"below {SUCCESS_WARNING:g}" in warning
    assert check_success(result(4), min_success=0.4) == warning  # at the threshold: a warning, not an error
    with pytest.raises(DemoError) as e:
        check_success(result(4), min_success=0.9)
    assert str(e.value) == "pick.zarr: expert success 0.40 < --min-success 0.9 (10 episodes stay stored)"
    with pytest.raises(DemoError, match=r"--min-success: must be a fraction in \[0, 1\]"):
        check_success(result(10), min_success=90)
    assert warning.endswith("check the robot config and the task options")  # the expert itself: blame the set-up
    with pytest.raises(DemoError, match="the expert succeeded on none of 10 episodes"):
        check_success(result(0))  # whatever --min-success says
    noisy = CollectResult("pick.zarr", 10, 4, frames=100, seconds=1.0, modes={}, operator="okay", noise=0.1)
    assert check_success(noisy).endswith("as --operator okay and --noise 0.1 may cause (the expert alone: "
                                         "--operator expert, no --noise)")  # asked for: not the robot's fault


@pytest.mark.slow
def test_cli_min_success_fails_and_keeps_the_episodes(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # The poor operator profile drops or misses the cube: 0 of these 3 pick episodes succeed.
    argv = ["collect", "--task", "pick", "--operator", "poor", "--episodes", "3", "--seed", "0", "--workers", "0"]
    strict = tmp_path / "strict.zarr"
    assert main([*argv, "--out", str(strict), "--min-success", "0.9"]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith(("error:", "warning:"))]
    assert err == [f"error: {strict}: expert success 0.00 < --min-success 0.9 (3 episodes stay stored)"]
    store = EpisodeStore.open(strict)
    assert store.num_episodes == 3 and not store.column("success").any() and store.verify() == []

    lenient = tmp_path / "lenient.zarr"
    assert main([*argv, "--out", str(lenient), "--json", "-"]) == 0
    captured = capsys.readouterr()
    assert '"success_rate": 0.0' in captured.out  # stdout stays pure JSON
    warnings = [line for line in captured.err.splitlines() if line.startswith(("error:", "warning:"))]
    assert warnings == [f"warning: {lenient}: expert success 0.00 (0/3 episodes) is below 0.9, as --operator poor "
                        "may cause (the expert alone: --operator expert, no --noise)"]
    assert EpisodeStore.open(lenient).num_episodes == 3


def test_cli_min_success_bad_values(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    for argv, needle in [
        (["--min-success", "1.5"], "--min-success"),
        (["--source", "vr", "--input", str(tmp_path / "p.jsonl"), "--min-success", "0.5"], "--source scripted"),
    ]:
        rc = main(["collect", "--task", "reach", "--episodes", "1", "--out", str(tmp_path / "x.zarr"), *argv])
        err = capsys.readouterr().err.strip()
        assert rc != 0 and len(err.splitlines()) == 1 and needle in err, (argv, err)
        assert not (tmp_path / "x.zarr").exists()
