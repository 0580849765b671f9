"""`demo bench policies` end to end on a tiny setting: one dataset, each policy trained and evaluated
on the same seeds, one JSON and one PNG; a rerun reuses what is complete."""

from __future__ import annotations

import json

import pytest

from demo.errors import DemoError

pytestmark = [pytest.mark.usefixtures("torch_one_thread"), pytest.mark.slow]  # one policy per class: ~22 s


def test_bench_policies_tiny_end_to_end(tmp_path, capfd) -> None:
    from demo.experiments.policies import PoliciesConfig, run
    from demo.cli.main import main

    out, report = tmp_path / "bench", tmp_path / "policies.json"
    argv = ["bench", "policies", "--task", "avoid", "--out", str(out), "--episodes-demo", "4", "--eval-episodes", "2",
            "--policies", "mse-bc,one-step", "--steps", "20", "--distil-steps", "6", "--starts", "2", "--samples", "2",
            "--latency-seconds", "0.02", "--json", str(report)]
    assert main(argv) == 0
    r = json.loads(report.read_text())
    assert r["benchmark"] == "policies" and r["task"] == "avoid" and (out / "policies.png").stat().st_size > 0
    assert [row["policy"] for row in r["rows"]] == ["mse-bc", "one-step"]
    for row in r["rows"]:
        s, both = row["success"], row["both_sides"]
        assert s["episodes"] == 2 and 0 <= s["successes"] <= 2 and len(s["ci95"]) == 2
        assert both["starts"] == 2 and both["samples"] == 2 and 0 <= both["starts_with_both"] <= 2
        assert sum(both["modes"].values()) == 4 and row["train_seconds"] > 0 and row["latency"]["ms_per_query"] > 0
    mse, student = r["rows"]
    assert mse["train_steps"] == 20 and student["train_steps"] == 6
    # the student's teacher was trained for it (not a row of the table) and timed apart
    assert student["teacher"] == "diffusion" and student["teacher_train_seconds"] > 0
    assert json.loads((out / "runs" / "one-step" / "run.json").read_text())["distilled_from"]["run"].endswith("diffusion")
    table = capfd.readouterr().out
    assert "MSE-BC" in table and "one-step" in table and f"(+{student['teacher_train_seconds']:,.0f})" in table

    # a rerun trains nothing again and evaluates nothing again: the same rows, faster; with --json -
    # stdout holds the JSON alone
    capfd.readouterr()
    assert main([*argv[:-4], "--latency-seconds", "0", "--json", "-"]) == 0
    again = json.loads(capfd.readouterr().out)
    assert [row["success"] for row in again["rows"]] == [row["success"] for row in r["rows"]]
    assert [row["train_seconds"] for row in again["rows"]] == [row["train_seconds"] for row in r["rows"]]
    assert again["seconds"] < r["seconds"]

    # other training settings in the same --out, or an unknown policy: one line, nothing run
    with pytest.raises(DemoError, match="trained with other steps"):
        run(PoliciesConfig(out=str(out), task="avoid", episodes_demo=4, policies=("mse-bc",), steps=21, distil_steps=6))
    capfd.readouterr()
    assert main(["bench", "policies", "--out", str(tmp_path / "other"), "--policies", "mse-bc,transformer"]) == 1
    err = capfd.readouterr().err.strip()
    assert err.startswith("error: --policies: unknown policy transformer") and "\n" not in err
    assert not (tmp_path / "other").exists()
