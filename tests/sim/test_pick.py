"""pick: the grasp-and-lift expert succeeds, decides from the state alone, and recovers."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.rollout import run_expert
from demo.sim.task import place_free_body


@pytest.fixture(scope="module")
def env():
    e = make_env("pick")
    yield e
    e.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_expert_picks(env, seed):
    r = run_expert(env, seed)
    assert r.success and r.first_success_step is not None and r.length < env.horizon
    assert env.observe()["obs.object_pos"][0, 2] > 0.12


def test_varied_operator_styles_succeed(env):
    for seed in (3, 4):
        assert run_expert(env, seed, rng=np.random.default_rng(seed), vary=True).success
    assert run_expert(env, 5, speed=0.6).success


def test_expert_is_a_function_of_the_state(env):
    """A fresh expert asked mid-episode answers exactly like the one that has been acting."""
    env.reset(6)
    acting = env.expert(np.random.default_rng(9), vary=True)
    for t in range(40):
        if t % 6 == 0:
            fresh = env.expert(np.random.default_rng(9), vary=True)
            np.testing.assert_allclose(fresh.act(env), acting.act(env), atol=1e-12)
        env.step(acting.act(env))


def test_recovers_when_the_cube_is_taken_from_the_hand(env):
    state = {"done": False}

    def snatch(e, t):
        cube = e.observe()["obs.object_pos"][0]
        if not state["done"] and cube[2] > 0.05:  # lifted: put it back on the table elsewhere
            place_free_body(e, e.task.joint, np.array([0.45, -0.15, e.task.half]), 0.4)
            state["done"] = True

    r = run_expert(env, 7, perturb=snatch)
    assert state["done"] and r.success


def test_recovers_from_a_pushed_arm(env):
    def shove(e, t):
        if t == 12:
            q = e.data.qpos[e.arm_qadr] + np.array([0.3, -0.2, 0.2, 0.2, -0.3, 0.2, 0.4])
            e.set_arm(q)

    assert run_expert(env, 8, perturb=shove).success


def test_coloured_cubes_the_words_name_the_target(tmp_path, one_line_error):
    """colours=3: three cubes apart, the episode's instruction names the one the expert lifts (and the only
    one success counts); the instruction reaches the store; held-out wording changes only the words."""
    from demo.cli.main import main
    from demo.store import EpisodeStore

    env = make_env("pick", colours=3)
    told = set()
    for seed in range(6):
        r = run_expert(env, seed)
        pos = env.observe()["obs.object_pos"]
        target = env.task.target
        assert r.success and env.instruction.split()[-2] == ("red", "green", "blue")[target]
        assert pos[target, 2] > 0.1 and all(pos[k, 2] < 0.05 for k in range(3) if k != target)
        gaps = [np.hypot(*(pos[a, :2] - pos[b, :2])) for a, b in ((0, 1), (0, 2), (1, 2))]
        told.add(env.instruction)
    assert len(told) >= 3  # targets and templates vary with the seed
    held_out = make_env("pick", colours=3, phrasing="held_out")
    held_out.reset(0)
    env.reset(0)
    assert held_out.task.target == env.task.target and held_out.instruction not in {
        t.format(c) for t in ("pick up the {} cube", "lift the {} cube", "grab the {} block") for c in ("red", "green", "blue")}
    np.testing.assert_array_equal(held_out.observe()["obs.object_pos"], env.observe()["obs.object_pos"])
    assert min(gaps) >= 0.09 - 1e-3
    assert main(["collect", "--task", "pick", "--task-opt", "colours=2", "--episodes", "3", "--workers", "0",
                 "--out", str(tmp_path / "c2.zarr")]) == 0
    with EpisodeStore.open(tmp_path / "c2.zarr") as store:
        assert store.meta.features["obs.object_pos"].shape == (2, 3) and all(store.column("instruction"))
        assert store.meta.task["options"] == {"colours": 2}
    one_line_error(["collect", "--task", "pick", "--task-opt", "colours=4", "--episodes", "1", "--out",
                    str(tmp_path / "x.zarr")], "colours must be 0")
    one_line_error(["collect", "--task", "pick", "--task-opt", "colours", "--episodes", "1", "--out",
                    str(tmp_path / "x.zarr")], "--task-opt", "KEY=VALUE")


def test_every_goal_repeats_each_scene_once_per_cube(tmp_path, one_line_error):
    """--every-goal: three consecutive episodes share a reset seed, so their first frames are the same images,
    and ask for the three cubes (the first for the one the seed draws); each is lifted by the expert. A task
    whose words choose no goal is refused in one line, with nothing written."""
    from demo.cli.main import main
    from demo.seeds import episode_seed
    from demo.store import EpisodeStore

    out = tmp_path / "every.zarr"
    assert main(["collect", "--task", "pick", "--task-opt", "colours=3", "--every-goal", "--episodes", "4",
                 "--camera", "front@32x32", "--seed", "5", "--workers", "0", "--out", str(out)]) == 0
    plain = make_env("pick", colours=3)
    plain.reset(episode_seed(5, 0))
    with EpisodeStore.open(out) as store:
        seeds = store.column("seed").tolist()
        told = store.column("instruction").tolist()
        assert seeds[:3] == [episode_seed(5, 0)] * 3 and seeds[3] == episode_seed(5, 1)
        assert told[0] == plain.instruction  # the seed's own goal first, as a plain collection asks
        colours = [t.split()[-2] for t in told[:3]]
        assert sorted(colours) == ["blue", "green", "red"] and len({t.split()[0] for t in told[:3]}) == 1
        assert all(store.column("success"))
        first = [store.read_episode(i, ["obs.image_front", "obs.object_pos"]) for i in range(3)]
        for ep in first[1:]:
            np.testing.assert_array_equal(ep["obs.image_front"][0], first[0]["obs.image_front"][0])
            np.testing.assert_array_equal(ep["obs.object_pos"][0], first[0]["obs.object_pos"][0])
        lifted = [int(np.argmax(ep["obs.object_pos"][-1][:, 2])) for ep in first]
        assert [("red", "green", "blue")[k] for k in lifted] == colours
    one_line_error(["collect", "--task", "pick", "--every-goal", "--episodes", "2", "--out", str(tmp_path / "x.zarr")],
                   "--every-goal", "names no choice of goal")
    one_line_error(["collect", "--task", "avoid", "--every-goal", "--episodes", "2", "--out", str(tmp_path / "x.zarr")],
                   "--every-goal", "names no choice of goal")  # its pairs are sides, not goals named in words
    assert not (tmp_path / "x.zarr").exists()
