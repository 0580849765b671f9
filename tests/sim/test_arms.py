"""Robots of several arms (demo.sim.arms): a TOML listing arm configs, checked arm by arm; gym-aloha's ViperX pair as
the worked example (it skips, saying why, without gym-aloha's files); arms that overlap refused in one line."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import pytest

from demo.cli.main import main
from demo.sim.arms import load_arms
from demo.sim.robot import BUILTIN_CONFIG

ROBOTS = Path(__file__).resolve().parents[2] / "sim" / "assets" / "robots"


@pytest.mark.skipif(importlib.util.find_spec("gym_aloha") is None,
                    reason="gym-aloha==0.1.5 is not installed (pip install --no-deps gym-aloha==0.1.5 runs this pair)")
def test_gym_alohas_pair_loads_in_its_action_order_and_each_arm_passes_the_check(tmp_path: Path) -> None:
    arms = load_arms(ROBOTS / "aloha_vx300s.toml")
    assert arms.arm_names == ("left", "right") and [a.arm_prefix for a in arms.arms] == ["vx300s_left/", "vx300s_right/"]
    names = arms.action_names
    assert len(names) == 14 and names[0] == "left.waist" and names[6] == "left.gripper" and names[13] == "right.gripper"
    out = tmp_path / "check.json"
    assert main(["robot", "check", str(ROBOTS / "aloha_vx300s.toml"), "--episodes", "2", "--targets", "1",
                 "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["robot"] == "aloha_vx300s" and set(report["arms"]) == {"left", "right"}
    assert all(r["experts"]["pick"]["successes"] == 2 for r in report["arms"].values())


def two_arms(tmp_path: Path, first: str, second: str, top: str = 'name = "pair"') -> Path:
    path = tmp_path / "pair.toml"
    path.write_text(f"{top}\n[[arms]]\n{first}\n[[arms]]\n{second}\n")
    return path


BUILTIN = f'config = "{BUILTIN_CONFIG}"'


@pytest.mark.parametrize("first, second, top, needle", [
    (f'name = "a"\n{BUILTIN}', f'name = "b"\n{BUILTIN}', 'name = "pair"', "arms 'a' and 'b' share the joint"),
    (f'name = "a"\n{BUILTIN}', f'name = "a"\n{BUILTIN}', 'name = "pair"', "two arms are named 'a'"),
    (f'name = "a"\n{BUILTIN}', BUILTIN, 'name = "pair"', "arm 2 needs a 'name'"),
    (f'name = "a"\n{BUILTIN}', f'name = "b"\n{BUILTIN}\nhome = [0, 0]', 'name = "pair"', "'config' names an arm config file"),
    (f'name = "a"\n{BUILTIN}', 'name = "b"\nmjcf = "none.xml"', 'name = "pair"', "arm 'b': robot config lacks arm_joints"),
    (f'name = "a"\n{BUILTIN}', f'name = "b"\n{BUILTIN}', 'name = "pair"\nspeed = 2', "not speed"),
])
def test_arms_that_overlap_or_are_ill_written_fail_in_one_line(tmp_path: Path, one_line_error: Any, first: str,
                                                                 second: str, top: str, needle: str) -> None:
    path = two_arms(tmp_path, first, second, top)
    one_line_error(["robot", "check", str(path), "--episodes", "1", "--targets", "1"], "pair.toml", needle)


def test_one_arm_only_and_a_task_given_several_arms_fail_in_one_line(tmp_path: Path, one_line_error: Any) -> None:
    one = tmp_path / "one.toml"
    one.write_text(f'name = "one"\n[[arms]]\nname = "a"\n{BUILTIN}\n')
    one_line_error(["robot", "check", str(one)], "one.toml", "two or more arms")
    pair = two_arms(tmp_path, f'name = "a"\n{BUILTIN}', f'name = "b"\n{BUILTIN}')
    out = tmp_path / "x.zarr"
    one_line_error(["collect", "--task", "reach", "--episodes", "1", "--robot", str(pair), "--out", str(out)],
                   "pair.toml", "demo's tasks take one arm")
    assert not out.exists()
