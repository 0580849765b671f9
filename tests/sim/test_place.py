"""place: the words name a (cube, pad) pair; the expert puts that cube on that pad from any state; held-out
pairs and paraphrases change only the goal and the words, never the scene."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.place import HELD_OUT_PAIRS, PHRASINGS, TRAIN_PAIRS
from demo.sim.rollout import run_expert

NAMES = ("red", "green", "blue")


@pytest.mark.parametrize("pairs", ["train", "held_out"])
def test_the_expert_puts_the_named_cube_on_the_named_pad(pairs: str) -> None:
    env = make_env("place", pairs=pairs)
    goals = set()
    for seed in range(6):
        r = run_expert(env, seed)
        cube, pad = env.task.pair(env)
        words = env.instruction.split()
        assert r.success and words[words.index("cube" if "cube" in words else "block") - 1] == NAMES[cube]
        assert words[-2] == NAMES[pad]
        obs = env.observe()
        assert np.hypot(*(obs["obs.object_pos"][cube, :2] - obs["obs.pad_pos"][pad, :2])) < 0.02
        assert (cube, pad) in (TRAIN_PAIRS if pairs == "train" else HELD_OUT_PAIRS)
        goals.add((cube, pad))
    assert len(goals) >= 2
    env.close()


def test_held_out_goals_and_words_leave_the_scene_as_it_was() -> None:
    """The same seed draws the same scene whatever the pairs and phrasing; nothing observed names the goal."""
    a, b = make_env("place"), make_env("place", pairs="held_out", phrasing="held_out")
    a.reset(3), b.reset(3)
    for key, value in a.observe().items():
        np.testing.assert_array_equal(value, b.observe()[key], err_msg=key)
    assert a.task.pair(a) in TRAIN_PAIRS and b.task.pair(b) in HELD_OUT_PAIRS
    seen = {t.format(cube=c, pad=p) for t in PHRASINGS["train"] for c in NAMES for p in NAMES}
    assert a.instruction in seen and b.instruction not in seen
    # every colour is in training both as a cube and as a pad; red and green never together
    assert {c for c, _ in TRAIN_PAIRS} == {p for _, p in TRAIN_PAIRS} == {0, 1, 2}
    assert not {(0, 1), (1, 0)} & set(TRAIN_PAIRS) and {(0, 2), (2, 0), (1, 2), (2, 1)} <= set(TRAIN_PAIRS)
    a.close(), b.close()


def test_the_expert_follows_the_named_cube_when_the_cubes_are_swapped() -> None:
    """State feedback: the named cube and another swap places mid-approach; the expert goes to where the named
    one is now and still finishes the pair."""
    from demo.sim.task import place_free_body

    env = make_env("place")
    moved = []

    def swap(e, t: int) -> None:
        if t == 10:
            task, (cube, _) = e.task, e.task.pair(e)
            other = next(i for i in range(3) if i != cube)
            boxes = task.boxes(e)
            a, b = boxes[cube].pos.copy(), boxes[other].pos.copy()
            place_free_body(e, task.joints[cube], b, 0.0)
            place_free_body(e, task.joints[other], a, 0.0)
            moved.append(b)

    assert run_expert(env, 4, perturb=swap).success and moved
    env.close()


def test_bad_options_fail_in_one_line(tmp_path, one_line_error) -> None:
    out = str(tmp_path / "x.zarr")
    one_line_error(["collect", "--task", "place", "--task-opt", "pairs=some", "--episodes", "1", "--out", out],
                   "pairs must be one of train, held_out, all")
    one_line_error(["collect", "--task", "place", "--task-opt", "cube_size=0.1", "--episodes", "1", "--out", out],
                   "cube_size")
