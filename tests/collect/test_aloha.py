"""The scripted bimanual experts of gym-aloha's tasks (demo.collect.aloha): IK on both arms, servo targets that
hold the arms against gravity, success in gym-aloha's own environment, run by its own interpreter
(DEMO_GYM_ALOHA_PYTHON: gym-aloha needs MuJoCo < 3.9, demo MuJoCo 4), and in the same scene rebuilt in demo's
MuJoCo (demo.sim.aloha_scene), whose simulator state is saved and restored exactly."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from demo.cli.main import main
from demo.store import EpisodeStore

ALOHA_PYTHON = os.environ.get("DEMO_GYM_ALOHA_PYTHON")
HAS_MJCF = importlib.util.find_spec("gym_aloha") is not None
needs_mjcf = pytest.mark.skipif(not HAS_MJCF, reason="gym-aloha==0.1.5 is not installed beside demo (pip install "
                                "--no-deps gym-aloha==0.1.5: its MJCF is the experts' IK model)")
needs_env = pytest.mark.skipif(not (HAS_MJCF and ALOHA_PYTHON), reason="DEMO_GYM_ALOHA_PYTHON names no interpreter "
                               "with gym-aloha (python -m venv aloha && aloha/bin/pip install gym-aloha==0.1.5)")
START = np.array([0, -0.96, 1.16, 0, -0.3, 0] * 2)  # gym-aloha's START_ARM_POSE, arm joints only


@needs_mjcf
def test_the_ik_puts_both_tcps_on_their_targets() -> None:
    from demo.collect.aloha import BimanualIK, aloha_mjcf, facing

    ik = BimanualIK(aloha_mjcf("transfer_cube"))
    start = ik.tcp(START)
    targets = [(start[0] + [0.08, 0.03, -0.15], facing(0, pitch=np.radians(45))),
               (start[1] + [-0.06, -0.04, -0.2], facing(1, pitch=np.radians(60), roll=np.radians(20)))]
    q = START
    for _ in range(4):  # each solve takes a few Gauss-Newton steps from the measured joints
        q = ik.solve(q, targets)
    for arm, (tcp, (target, rot)) in enumerate(zip(ik.tcp(q), targets)):
        assert np.linalg.norm(tcp - target) < 2e-3, arm
        link = ik.configuration.data.body(f"vx300s_{'left' if arm == 0 else 'right'}/gripper_link")
        cos = (np.trace(rot.T @ link.xmat.reshape(3, 3)) - 1) / 2
        assert np.arccos(np.clip(cos, -1, 1)) < 0.02, arm


@needs_mjcf
def test_servo_targets_hold_the_arms_where_the_plain_targets_let_them_sag() -> None:
    """In gym-aloha's scene (MuJoCo 4 here), two seconds of commands: the joint positions themselves sag
    under gravity (the wrists' servos are soft); the gravity-corrected targets hold them."""
    from demo.collect.aloha import BimanualIK, aloha_mjcf

    ik = BimanualIK(aloha_mjcf("transfer_cube"))
    model = mujoco.MjModel.from_xml_path(str(aloha_mjcf("transfer_cube")))
    want = START + np.array([0.2, 0.3, -0.4, 0.1, 0.6, 0.0] * 2)  # arms forward, wrists loaded
    errors = []
    for command in (want, ik.servo_targets(want)):
        data = mujoco.MjData(model)
        for arm in range(2):
            data.qpos[8 * arm: 8 * arm + 6] = want[6 * arm: 6 * arm + 6]
            data.ctrl[8 * arm: 8 * arm + 6] = command[6 * arm: 6 * arm + 6]
            data.ctrl[8 * arm + 6: 8 * arm + 8] = [0.04, -0.04]
        for _ in range(1000):
            mujoco.mj_step(model, data)
        reached = np.r_[data.qpos[0:6], data.qpos[8:14]]
        errors.append(np.abs(reached - want).max())
    assert errors[1] < 0.01 and errors[0] > 3 * errors[1], errors


def collect(out: Path, task: str, episodes: int, *extra: str) -> EpisodeStore:
    assert main(["collect", "--env", f"process:aloha_state:{task}", "--env-opt", f"python={ALOHA_PYTHON}",
                 "--env-opt", "pixels=false", "--expert", f"demo.collect.aloha:{task}", "--episodes", str(episodes),
                 "--seed", "7", "--workers", "0", "--out", str(out), *extra]) == 0
    return EpisodeStore.open(out)


@pytest.mark.slow
@needs_env
def test_the_experts_succeed_in_gym_alohas_own_environment(tmp_path: Path) -> None:
    """gym-aloha's physics, reward and success (reward 4) judge them; its observation gains the objects'
    poses (env_state), which the experts read."""
    cube = collect(tmp_path / "cube.zarr", "transfer_cube", 4)
    assert [cube.episode_info(i)["success"] for i in range(4)] == [True] * 4
    episode = cube.read_episode(0)
    assert episode["obs.agent_pos"].shape[1] == 14 and episode["obs.env_state"].shape[1] == 7
    assert episode["action"].shape[1] == 14 and len(episode["action"]) < 300  # it ends at success
    insertion = collect(tmp_path / "insertion.zarr", "insertion", 4)
    assert sum(insertion.episode_info(i)["success"] for i in range(4)) >= 3
    assert insertion.read_episode(0)["obs.env_state"].shape[1] == 14


@needs_env
def test_an_unknown_aloha_task_is_one_line(tmp_path: Path, one_line_error: Any) -> None:
    one_line_error(["collect", "--env", "process:aloha_state:juggle", "--env-opt", f"python={ALOHA_PYTHON}",
                    "--expert", "demo.collect.aloha:transfer_cube", "--episodes", "1", "--out", str(tmp_path / "x.zarr")],
                   "juggle")


@pytest.mark.slow
@needs_env
def test_the_aloha_suite_in_miniature(tmp_path: Path) -> None:
    """`demo bench suite aloha`: collected in gym-aloha with pixels, ACT trained from the top camera and the joints
    (not env_state), judged in gym-aloha on held-out seeds, set beside the paper's figure."""
    import json

    out = tmp_path / "suite.json"
    assert main(["bench", "suite", "aloha", "--python", str(ALOHA_PYTHON), "--tasks", "transfer_cube", "--demos", "2",
                 "--episodes", "1", "--steps", "20", "--camera", "top@32x24", "--out", str(tmp_path / "runs"),
                 "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    (task,) = result["tasks"]
    assert result["algo"] == "act" and task["expert"]["successes"] == 2 and task["policy"]["episodes"] == 1
    assert task["published"]["success_rate"] == 0.9 and task["seeds_shared_with_training_data"] == 0
    run = json.loads((tmp_path / "runs" / "transfer_cube" / "act" / "run.json").read_text())
    assert run["policy"]["obs"]["keys"] == ["obs.agent_pos"] and run["policy"]["spec"]["images"] == [
        ["obs.image_pixels_top", 24, 32]]


def test_the_aloha_suite_needs_gym_alohas_interpreter(tmp_path: Path, one_line_error: Any) -> None:
    one_line_error(["bench", "suite", "aloha", "--out", str(tmp_path / "runs")], "--python", "gym-aloha==0.1.5")


def test_a_task_trains_with_its_own_chunk_where_the_suite_measured_one() -> None:
    """gym-aloha's insertion trains ACT on 50-step chunks (measured better there), transfer cube on ACT's default;
    --chunk overrides both, another --algo gets the suite's chunk, not one measured for ACT."""
    from demo.experiments.suite import SuiteConfig, task_chunk

    aloha = SuiteConfig(suite="aloha", python="python")
    assert task_chunk(aloha, "insertion") == 50 and task_chunk(aloha, "transfer_cube") is None
    assert task_chunk(SuiteConfig(suite="aloha", chunk=16), "insertion") == 16
    assert task_chunk(SuiteConfig(suite="aloha", algo="diffusion"), "insertion") is None
    assert task_chunk(SuiteConfig(), "reach-v3") == 1  # Meta-World: single-step


def scene_episode(env: Any, task: str, seed: int, steps: int = 300) -> tuple[list[float], dict[str, np.ndarray]]:
    from demo.collect.aloha import AlohaExpert

    obs, _ = env.reset(seed=seed)
    expert, rewards = AlohaExpert(task), []
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(expert.act(obs))
        rewards.append(reward)
        if terminated or truncated:
            break
    return rewards, obs


@needs_mjcf
@pytest.mark.parametrize("task", ["transfer_cube", "insertion"])
def test_the_experts_succeed_in_the_scene_rebuilt_in_demos_mujoco(task: str) -> None:
    """gym-aloha's scene, reset draw, action convention and reward, rebuilt here: the experts reach reward 4 through
    gym-aloha's stages in order (the right hand's grasp or both grasps first)."""
    from demo.sim.aloha_scene import AlohaScene

    env = AlohaScene(task)
    for seed in (3, 4):
        rewards, obs = scene_episode(env, task, seed)
        assert rewards[-1] == 4 and len(rewards) < 300, (seed, max(rewards))
        first = [next(i for i, r in enumerate(rewards) if r >= k) for k in (1, 2, 3, 4)]
        assert first == sorted(first) and first[0] > 50  # nothing is touched before the hands get there
        assert obs["env_state"].shape == ((7,) if task == "transfer_cube" else (14,))


@needs_mjcf
def test_a_saved_scene_state_restores_exactly() -> None:
    from demo.collect.aloha import AlohaExpert
    from demo.sim.aloha_scene import AlohaScene, initial_poses

    env = AlohaScene("transfer_cube")
    obs, _ = env.reset(seed=11)
    assert np.array_equal(obs["env_state"], initial_poses("transfer_cube", 11))  # gym-aloha's draw for seed 11
    expert = AlohaExpert("transfer_cube")
    for _ in range(120):  # the cube is in the right hand
        obs, *_ = env.step(expert.act(obs))
    saved, actions = env.get_state(), [expert.act(obs) for _ in range(1)] * 30
    runs = []
    for _ in range(2):
        env.set_state(saved)
        runs.append([env.step(a)[0]["agent_pos"].copy() for a in actions])
    assert env.t == 150 and np.array_equal(np.array(runs[0]), np.array(runs[1]))


@needs_env
def test_the_rebuilt_scene_starts_as_gym_aloha_does() -> None:
    """The same seed puts the objects where gym-aloha puts them and renders the same top camera image, and the arms'
    first second under the expert stays within 0.005 of gym-aloha's (MuJoCo 4 against 3.8: close, not identical)."""
    from demo.collect.aloha import AlohaExpert
    from demo.sim.aloha_scene import AlohaScene
    from demo.sim.process_env import ProcessEnv

    for task in ("transfer_cube", "insertion"):
        theirs = ProcessEnv(f"aloha_state:{task}", str(ALOHA_PYTHON), {"width": 64, "height": 48})
        mine = AlohaScene(task, pixels=True, width=64, height=48)
        try:
            a, _ = theirs.reset(seed=5)
            b, _ = mine.reset(seed=5)
            np.testing.assert_allclose(a["agent_pos"], b["agent_pos"], atol=1e-9)
            np.testing.assert_allclose(a["env_state"], b["env_state"], atol=1e-9)
            assert np.abs(a["pixels"]["top"].astype(int) - b["pixels"]["top"]).mean() < 0.5
            ea, eb = AlohaExpert(task), AlohaExpert(task)
            for _ in range(50):
                a = theirs.step(ea.act(a))[0]
                b = mine.step(eb.act(b))[0]
            assert np.abs(a["agent_pos"] - b["agent_pos"]).max() < 5e-3
        finally:
            theirs.close()
            mine.close()
