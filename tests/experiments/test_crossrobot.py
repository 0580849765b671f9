"""`demo bench crossrobot` end to end at toy size: two arms (the built-in Panda and robosuite's UR5e),
the union, per-arm and joint policies, the refusals recorded, every row evaluated on the asked arm."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.training.data import ROBOT_AGNOSTIC_KEYS

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("robosuite") is None,
                       reason="the UR5e's model files come from robosuite (pip install --no-deps robosuite==1.5.2)"),
    pytest.mark.slow,  # two arms, five policies, eight evaluations (~14 s in miniature)
]


def test_crossrobot_at_toy_size(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x"
    assert main(["bench", "crossrobot", "--out", str(out), "--demos", "4", "--episodes", "1", "--steps", "20",
                 "--json", "-"]) == 0
    result = json.loads(capfd.readouterr().out)  # stdout holds only the JSON
    arms = list(result["arms"])
    assert arms == ["panda_prim", "robosuite_ur5e"]
    assert [result["arms"][a]["dof"] for a in arms] == [7, 6]
    plan = [(r["policy"], r["robot"], r["trained_on_robot"]) for r in result["rows"]]
    assert plan == [("union_ee7", "panda_prim", True), ("union_ee7", "robosuite_ur5e", True),
                    ("ee7_panda_prim", "panda_prim", True), ("ee7_panda_prim", "robosuite_ur5e", False),
                    ("ee7_robosuite_ur5e", "panda_prim", False), ("ee7_robosuite_ur5e", "robosuite_ur5e", True),
                    ("joint_panda_prim", "panda_prim", True), ("ee7_panda_prim_joint_obs", "panda_prim", True)]
    assert all(r["episodes"] == 1 for r in result["rows"])
    assert "joint-space actions of arms with different joints cannot share a policy" in result["refusals"]["union_joint"]
    assert "observation obs.joint_pos is (6,) here and (7,)" in result["refusals"]["union_ee7_default_obs"]
    union = json.loads((out / "runs" / "union_ee7" / "run.json").read_text())
    assert [r["name"] for r in union["robots"]] == arms
    assert union["policy"]["obs"]["keys"] == list(ROBOT_AGNOSTIC_KEYS)
    assert set(result["union_vs_per_arm"]) == set(arms) and isinstance(result["meets_target"], bool)
