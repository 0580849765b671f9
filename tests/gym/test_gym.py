"""The tasks as Gymnasium environments: the API checker, spaces against a store, seeds, episode end, the expert."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import demo.gym
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.gym.trajectories import trajectories
from demo.seeds import episode_seed
from demo.sim.avoid import OBSTACLE_HALF
from demo.sim.rollout import run_expert
from demo.sim.tasks import TASK_NAMES
from demo.store import EpisodeStore

# What check_env may say about our spaces, by design (demo.gym.spaces): velocities have no known bounds,
# and actions are in the store's units (rad) unless normalize_actions.
ALLOWED_WARNINGS = (
    "A Box observation space minimum value is -infinity",
    "A Box observation space maximum value is infinity",
    "For Box action spaces, we recommend using a symmetric and normalized space",
)
CAMERAS = ["front@32x32", "wrist@32x32"]


def checked(env_id: str, **options) -> None:
    env = gymnasium.make(env_id, render_mode="rgb_array", render_camera="front@32x32", **options)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env.unwrapped)
        frame = env.unwrapped.render()  # after check_env's resets (the wrapper has not seen one)
    finally:
        env.close()
    unexpected = [str(w.message) for w in caught if not any(a in str(w.message) for a in ALLOWED_WARNINGS)]
    assert unexpected == []
    assert frame.shape == (32, 32, 3) and frame.dtype == np.uint8 and frame.std() > 0


def test_every_task_is_registered() -> None:
    assert list(demo.gym.ENV_IDS) == list(TASK_NAMES)
    assert demo.gym.ENV_IDS["pick"] == "demo/Pick-v0"
    assert all(i in gymnasium.registry for i in demo.gym.ENV_IDS.values())
    demo.gym.register_all()  # again: nothing changes


@pytest.mark.parametrize("task", TASK_NAMES)
def test_check_env_state(task: str) -> None:
    checked(demo.gym.ENV_IDS[task])


@pytest.mark.parametrize("task", [t if t == "reach" else pytest.param(t, marks=pytest.mark.slow) for t in TASK_NAMES])
def test_check_env_cameras(task: str) -> None:
    checked(demo.gym.ENV_IDS[task], cameras=CAMERAS)


def test_check_env_ee7_and_task_options() -> None:
    checked("demo/Pick-v0", action="ee7")
    env = gymnasium.make("demo/Stack-v0", blocks=2)
    assert env.observation_space["object_pos"].shape == (6,)  # a store's (2, 3), flat
    assert env.unwrapped.horizon == 260 and env.spec.max_episode_steps == 260  # the options' horizon
    env.close()


def test_spaces_and_first_observation_match_a_collected_store(tmp_path: Path) -> None:
    config = CollectConfig(task="pick", episodes=1, seed=3, cameras=(("front", 32, 32),))
    collect_scripted(config, tmp_path / "p.zarr", workers=0)
    store = EpisodeStore.open(tmp_path / "p.zarr")
    env = gymnasium.make("demo/Pick-v0", cameras=["front@32x32"])
    # Named as the store's features less their "obs." prefix.
    stored = {k.removeprefix("obs."): f for k, f in store.meta.features.items() if k.startswith("obs.")}
    assert set(env.observation_space.spaces) == set(stored)
    for key, space in env.observation_space.spaces.items():
        shape = stored[key].shape if key.startswith("image_") else (int(np.prod(stored[key].shape)),)  # low-dim: flat
        assert (space.shape, space.dtype) == (shape, np.dtype(stored[key].dtype)), key
    assert env.action_space.shape == (store.meta.action.dim,) and env.unwrapped.action_spec == store.meta.action
    # The reset seed is the store's seed column: the first observation is the stored frame 0, bit for bit.
    seed = int(store.column("seed")[0])
    assert seed == episode_seed(3, 0)
    obs, info = env.reset(seed=seed)
    assert info["seed"] == seed
    frame0 = store.read_episode(0, [f"obs.{k}" for k in stored])
    for key in stored:
        np.testing.assert_array_equal(obs[key], frame0[f"obs.{key}"][0].reshape(obs[key].shape), err_msg=key)
        assert env.observation_space[key].contains(obs[key]), key
    env.close()


@pytest.mark.parametrize("action", ["joint_pos", "ee7"])
def test_the_expert_succeeds_through_the_gym_api(action: str) -> None:
    for task in ("reach", "pick"):
        env = gymnasium.make(demo.gym.ENV_IDS[task], action=action)
        for i in range(3):
            obs, _ = env.reset(seed=episode_seed(0, i))
            expert = env.unwrapped.expert()
            for _ in range(env.unwrapped.horizon):
                a = expert.act(obs)
                assert a in env.action_space
                obs, reward, terminated, truncated, info = env.step(a)
                if terminated or truncated:
                    break
            assert terminated and info["success"] and reward == 1.0 and info["failure"] is None, (task, i)
        env.close()


def test_an_episode_terminates_when_collection_would_end_it() -> None:
    env = gymnasium.make("demo/Reach-v0").unwrapped
    seed = episode_seed(0, 1)
    expected = run_expert(env.sim, seed)  # the rollout loop collection and demo eval run
    obs, _ = env.reset(seed=seed)
    expert, rewards, steps, terminated = env.expert(), [], 0, False
    while not terminated:
        obs, reward, terminated, truncated, info = env.step(expert.act(obs))
        rewards.append(reward)
        steps += 1
    assert steps == expected.length
    first = expected.first_success_step
    assert rewards.index(1.0) + 1 == first and set(rewards[first - 1:]) == {1.0}

    # Holding still never succeeds: truncated exactly at the horizon.
    obs, _ = env.reset(seed=seed)
    hold = np.r_[obs["joint_pos"], obs["gripper"]]
    for t in range(env.horizon):
        obs, reward, terminated, truncated, info = env.step(hold)
        assert not terminated and reward == 0.0 and truncated == (t + 1 == env.horizon)
    env.close()


def test_a_collision_on_avoid_terminates() -> None:
    env = gymnasium.make("demo/Avoid-v0").unwrapped
    obs, _ = env.reset(seed=4)
    sim = env.sim
    ee = sim.ee_pose()[0]  # bring the obstacle to the hand
    sim.set_mocap_pose(sim.task.obstacle_mocap, np.array([ee[0] + 0.09, ee[1], OBSTACLE_HALF[2]]))
    obs, reward, terminated, truncated, info = env.step(np.r_[obs["joint_pos"], 0.0])
    assert terminated and not truncated and info == {"success": False, "failure": "collision"} and reward == 0.0
    env.close()


def test_same_seed_same_observations() -> None:
    def trajectory(seed: int) -> list[dict[str, np.ndarray]]:
        env = gymnasium.make("demo/Push-v0", action="ee7")
        env.action_space.seed(0)
        out = [env.reset(seed=seed)[0]]
        out += [env.step(env.action_space.sample())[0] for _ in range(5)]
        env.close()
        return out

    a, b, c = trajectory(7), trajectory(7), trajectory(8)
    for x, y in zip(a, b):
        assert all(np.array_equal(x[k], y[k]) for k in x)
    assert not np.array_equal(a[0]["object_pos"], c[0]["object_pos"])


def test_options_and_bad_input() -> None:
    env = gymnasium.make("demo/Reach-v0", obs_keys=["obs.ee_pos", "goal_pos"])  # store names or keys
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"ee_pos", "goal_pos"}
    env.close()
    env = gymnasium.make("demo/Reach-v0", obs_keys=["ee_pos"], store_layout=True)
    assert set(env.reset(seed=0)[0]) == {"obs.ee_pos"}
    with pytest.raises(DemoError, match="non-finite action"):
        env.step(np.full(env.action_space.shape, np.nan, dtype=np.float32))
    with pytest.raises(DemoError, match="unknown reset option"):
        env.reset(options={"state": 1})
    env.close()
    for options, needle in [
        ({"obs_keys": ["obs.nope"]}, "obs.nope"),
        ({"action": "torque"}, "unknown action representation"),
        ({"cameras": ["front@32"]}, "NAME@WIDTHxHEIGHT"),
        ({"cubes": 3}, "unknown task option"),
    ]:
        with pytest.raises(DemoError, match=needle):
            gymnasium.make("demo/Reach-v0", **options)
    with pytest.raises(DemoError, match="'human' is not supported"):  # gymnasium.make wraps rgb_array for human
        demo.gym.DemoEnv("reach", render_mode="human")


def test_the_seams_rl_and_trajectory_libraries_touch(tmp_path: Path) -> None:
    """Finite bounds where physical, flat keys, max_episode_steps in the spec, a normalised action option whose
    expert answers in it."""
    env = gymnasium.make("demo/Pick-v0", normalize_actions=True)
    try:
        space = env.observation_space
        assert all(len(b.shape) == 1 for b in space.spaces.values())
        assert np.isfinite(space["joint_pos"].low).all() and space["gripper"].high.tolist() == [np.float32(1.05)]
        assert space["object_quat"].low.tolist() == [-1.0] * 4 and np.isfinite(space["object_pos"].high).all()
        assert env.spec.max_episode_steps == env.unwrapped.horizon
        assert env.action_space.low.tolist() == [-1.0] * 8 and env.action_space.high.tolist() == [1.0] * 8
        obs, _ = env.reset(seed=episode_seed(0, 0))
        expert = env.unwrapped.expert()
        for _ in range(env.spec.max_episode_steps):
            action = expert.act(obs)
            assert env.action_space.contains(action)
            obs, reward, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        assert info["success"]
    finally:
        env.close()
    # An arm with a continuous joint has no finite joint_pos bounds to normalise to.
    from demo.sim.robot import BUILTIN_CONFIG

    xml = (BUILTIN_CONFIG.parent / "panda.xml").read_text().replace('<joint name="joint7"/>',
                                                                     '<joint name="joint7" limited="false" range="0 0"/>')
    (tmp_path / "cobot.xml").write_text(xml)
    (tmp_path / "cobot.toml").write_text(BUILTIN_CONFIG.read_text().replace('"panda.xml"', '"cobot.xml"'))
    with pytest.raises(DemoError, match="normalize_actions: the joint_pos action has an unbounded dimension"):
        gymnasium.make("demo/Pick-v0", normalize_actions=True, robot=str(tmp_path / "cobot.toml"))


def test_the_expert_answers_from_observations_over_a_vector_env() -> None:
    """``expert_policy()`` drives gymnasium's own vector env, rows in any order, and succeeds on every
    episode of every task, as the privileged expert does; it refuses what it cannot answer."""
    for task in TASK_NAMES:
        env_id = demo.gym.ENV_IDS[task]
        envs = gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(env_id, sim_state=True)] * 2)
        probe = gymnasium.make(env_id, sim_state=True)
        policy = probe.unwrapped.expert_policy()
        obs, _ = envs.reset(seed=[episode_seed(5, 0), episode_seed(5, 1)])
        done, success = np.zeros(2, bool), np.zeros(2, bool)
        while not done.all():
            flipped = {k: v[::-1] for k, v in obs.items()}  # rows in another order: answers follow the rows
            actions = policy.predict(flipped)[0][::-1]
            assert np.array_equal(actions, policy.predict(obs)[0])
            obs, _, terminated, truncated, info = envs.step(actions)
            success |= terminated & ~done & info["success"]
            done |= terminated | truncated
        assert success.all(), task
        policy.close()
        probe.close()
        envs.close()
    env = gymnasium.make("demo/Reach-v0")
    with pytest.raises(DemoError, match="make the env with sim_state=True"):
        env.unwrapped.expert_policy()
    env.close()
    with pytest.raises(DemoError, match="ee7 action is relative to the last executed command"):
        gymnasium.make("demo/Reach-v0", sim_state=True, action="ee7").unwrapped.expert_policy()
    pick = gymnasium.make("demo/Pick-v0", sim_state=True)
    policy = pick.unwrapped.expert_policy()
    obs, _ = gymnasium.make("demo/Reach-v0", sim_state=True).reset(seed=0)
    with pytest.raises(DemoError, match="not a batch of this env's"):
        policy.act(obs)  # a reach state for the pick expert
    pick.close()


def test_trajectories_rebuild_final_observations(tmp_path: Path) -> None:
    """A store's episodes with their final observations: stepping the actions live from the episode's seed
    gives every observation of the trajectory, the final one included, bit for bit."""
    config = CollectConfig(task="push", episodes=2, seed=1, cameras=(("front", 32, 32),))
    collect_scripted(config, tmp_path / "p.zarr", workers=0)
    env = gymnasium.make("demo/Push-v0", cameras=["front@32x32"])
    with EpisodeStore.open(tmp_path / "p.zarr") as store:
        trajs = list(trajectories(store, env))
        assert len(trajs) == 2 and all(t.terminal for t in trajs)
        for t in trajs:
            assert all(len(v) == len(t.actions) + 1 for v in t.obs.values())
            obs, _ = env.reset(seed=t.seed)
            for step, action in enumerate(t.actions):
                for key in obs:
                    np.testing.assert_array_equal(obs[key], t.obs[key][step], err_msg=key)
                obs, *_ = env.step(action)
            for key in obs:
                np.testing.assert_array_equal(obs[key], t.obs[key][-1], err_msg=key)
        for other, needle in [(gymnasium.make("demo/Pick-v0"), "holds 'push' episodes"),
                              (gymnasium.make("demo/Push-v0", action="ee7"), "not this env's absolute ee7"),
                              (gymnasium.make("demo/Push-v0", cameras=["side@32x32"]), "does not record obs.image_side"),
                              (gymnasium.make("demo/Push-v0", block_size=0.06), "seed does not give its recorded first")]:
            with pytest.raises(DemoError, match=needle):
                next(trajectories(store, other))
            other.close()
    env.close()
