"""Fixtures shared by several test modules."""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def torch_one_thread():
    """torch on one thread for a module: multi-threaded torch on a busy 2-core machine crawls."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def synthetic_store():
    """``make(path, episodes=24, length=30, seed=0) -> path``: a store whose actions are a smooth function
    of the observation (joint targets near ``obs.joint_pos``); every 6th episode failed."""
    from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta

    def make_store(path: Path, episodes: int = 24, length: int = 30, seed: int = 0) -> Path:
        """Actions are a fixed smooth function of the observation (plus a joint target near obs.joint_pos)."""
        meta = StoreMeta(
            fps=20.0,
            features={
                "obs.joint_pos": FeatureSpec((2,), "float32"),
                "obs.joint_vel": FeatureSpec((2,), "float32"),
                "obs.object_pos": FeatureSpec((1, 3), "float32"),
            },
            action=ActionSpec("joint_pos", ("j0.target", "j1.target", "gripper"), ("rad", "rad", "1")),
            robot={"name": "synthetic", "config": "builtin"},
            task={"name": "synthetic", "options": {}, "horizon": length},
        )
        rng = np.random.default_rng(seed)
        with EpisodeStore.create(path, meta) as store:
            for i in range(episodes):
                q = rng.uniform(-1, 1, (length, 2)).astype(np.float32)
                obj = rng.uniform(-1, 1, (length, 1, 3)).astype(np.float32)
                delta = 0.05 * np.tanh(obj[:, 0, :2] * 2)
                grip = (obj[:, 0, 2:] > 0).astype(np.float32)
                action = np.concatenate([q + delta, grip], axis=1)
                store.append_episode(
                    {"obs.joint_pos": q, "obs.joint_vel": np.zeros_like(q), "obs.object_pos": obj,
                     "action": action},
                    success=i % 6 != 5, seed=100 + i, source="synthetic",
                )
        return path

    return make_store


@pytest.fixture(scope="session")
def tiny_bc_config():
    """``make(data, out, **changes) -> TrainConfig``: a seconds-long single-step BC run of a small MLP."""
    from demo.training.config import TrainConfig

    def make(data: Path, out: Path, **changes) -> TrainConfig:
        base = dict(data=str(data), out=str(out), steps=300, batch_size=64, lr=3e-3, warmup_steps=20, chunk=1,
                    policy={"hidden": (64, 64)}, log_every=50, val_every=100)
        return TrainConfig(**{**base, **changes})

    return make


@pytest.fixture(scope="session")
def reach_demos(tmp_path_factory: pytest.TempPathFactory):
    """``make(episodes) -> path``: scripted ``reach`` demonstrations (seed 0) with the loose tolerances a
    seconds-long run can meet (pos_tol 0.04 m, rot_tol 0.4 rad), collected once per count (read-only)."""
    from demo.collect.scripted import CollectConfig, collect_scripted

    made: dict[int, Path] = {}

    def make(episodes: int = 8) -> Path:
        if episodes not in made:
            path = tmp_path_factory.mktemp("reach") / f"reach{episodes}.zarr"
            collect_scripted(CollectConfig(task="reach", episodes=episodes, seed=0,
                                           task_options={"pos_tol": 0.04, "rot_tol": 0.4}), path, workers=0)
            made[episodes] = path
        return made[episodes]

    return make


@pytest.fixture
def one_line_error(capsys: pytest.CaptureFixture[str]):
    """``check(argv, *needles, rc=None) -> line``: run ``demo ARGV`` in-process; it must fail (with exit code
    ``rc``, or any non-zero one) printing exactly one line on stderr, ``error: ...``, that holds every needle
    (and no traceback); return that line."""
    from demo.cli.main import main

    def check(argv: list[str], *needles: str, rc: int | None = None) -> str:
        capsys.readouterr()  # what came before is not this command's
        code = main(argv)
        err = capsys.readouterr().err
        assert (code == rc) if rc is not None else (code != 0), (code, err)
        assert err.startswith("error: ") and err.endswith("\n") and len(err.splitlines()) == 1, err
        assert "Traceback" not in err, err
        for needle in needles:
            assert needle in err, (needle, err)
        return err.strip()

    return check


@pytest.fixture
def replays():
    """``check(task, episode)``: from the episode's first recorded ``sim.state``, stepping its recorded ``action``
    reproduces every recorded state bit for bit (a human recording replays as it was recorded)."""
    from demo.sim import make_env

    def check(task: str, episode: dict[str, np.ndarray]) -> None:
        env = make_env(task)
        try:
            env.reset(0)
            env.set_state(episode["sim.state"][0])
            for t in range(len(episode["action"]) - 1):
                env.step(episode["action"][t])
                np.testing.assert_array_equal(env.get_state(), episode["sim.state"][t + 1], err_msg=f"step {t}")
        finally:
            env.close()

    return check


# The worked example of docs/environments.md: a point that must reach a goal, and its expert.
POINT_REACH = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np


    class PointReach(gym.Env):
        """A point in the unit square moves towards a goal; success within 5 cm of it."""

        metadata = {"render_modes": [], "render_fps": 10}

        def __init__(self, speed: float = 0.05):
            self.speed = speed
            self.observation_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)  # position, goal
            self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)  # velocity, in speed units

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.pos, self.goal = self.np_random.uniform(-0.8, 0.8, (2, 2))
            return self._obs(), {}

        def step(self, action):
            self.pos = np.clip(self.pos + self.speed * np.clip(action, -1, 1), -1, 1)
            success = bool(np.linalg.norm(self.pos - self.goal) < 0.05)
            return self._obs(), float(success), success, False, {"is_success": success}

        def _obs(self):
            return np.r_[self.pos, self.goal].astype(np.float32)


    def expert(obs, env):
        """Head for the goal at full speed (slower when close)."""
        return np.clip((obs[2:] - obs[:2]) / 0.05, -1.0, 1.0)


    gym.register("PointReach-v0", entry_point=PointReach, max_episode_steps=60)
''')


@pytest.fixture()
def user_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """The example as a user's own module ``point_reach`` in ``tmp_path/user``, importable here and in worker
    processes (tests/collect/test_foreign_env.py, test_process_env.py)."""
    folder = tmp_path / "user"
    folder.mkdir()
    (folder / "point_reach.py").write_text(POINT_REACH)
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setenv("PYTHONPATH", str(folder) + (":" + sys.path[0] if sys.path[0] else ""))
    yield "point_reach"
    sys.modules.pop("point_reach", None)
