"""An environment run by another interpreter (`--env process:NAME --env-opt python=PYTHON`, demo.sim.process_env):
the same episodes as in-process, through collection, training and `demo eval`; its errors and a worker that dies
in one line. The "other" interpreter here is this one (CI has no second venv; gym-aloha's, where one is built,
is docs/environments.md's case)."""

from __future__ import annotations

import json
import os
import signal
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.sim.process_env import ProcessEnv
from demo.store import EpisodeStore

POINT = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np


    class Point(gym.Env):
        """A point to move onto a goal, observed as gym-aloha observes: a Dict with a nested camera."""

        metadata = {"render_modes": [], "render_fps": 10}

        def __init__(self, speed=0.1):
            self.speed = speed
            self.observation_space = gym.spaces.Dict({
                "agent_pos": gym.spaces.Box(-1.0, 1.0, (2,), np.float64),
                "goal": gym.spaces.Box(-1.0, 1.0, (2,), np.float64),
                "pixels": gym.spaces.Dict({"top": gym.spaces.Box(0, 255, (8, 8, 3), np.uint8)}),
            })
            self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.pos, self.goal = self.np_random.uniform(-0.8, 0.8, (2, 2))
            return self._obs(), {}

        def step(self, action):
            self.pos = np.clip(self.pos + self.speed * np.clip(action, -1, 1), -1, 1)
            success = bool(np.linalg.norm(self.pos - self.goal) < 0.05)
            return self._obs(), float(success), False, False, {"is_success": success, "distance": np.float32(0.5)}

        def _obs(self):
            image = np.zeros((8, 8, 3), np.uint8)
            image[int((self.pos[1] + 1) * 3.5), int((self.pos[0] + 1) * 3.5)] = 255
            return {"agent_pos": self.pos.copy(), "goal": self.goal.copy(), "pixels": {"top": image}}


    def expert(obs, env):
        return np.clip((obs["goal"] - obs["agent_pos"]) / 0.1, -1.0, 1.0)


    gym.register("point_ns/Point-v0", entry_point=Point, max_episode_steps=40)
''')


@pytest.fixture
def point(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The environment as a user's package ``point_ns`` (registering ``point_ns/Point-v0`` on import), on the
    path of this process and of the worker it starts."""
    (tmp_path / "point_ns").mkdir()
    (tmp_path / "point_ns" / "__init__.py").write_text(POINT)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    return tmp_path


def collect(out: Path, env: str, *options: str) -> None:
    assert main(["collect", "--env", env, "--expert", "point_ns:expert", "--episodes", "3", "--seed", "4",
                 "--workers", "0", "--out", str(out), *options]) == 0


def test_the_same_episodes_as_in_process_through_collection_training_and_eval(point: Path, tmp_path: Path) -> None:
    collect(tmp_path / "here.zarr", "point_ns:point_ns/Point-v0")
    collect(tmp_path / "there.zarr", "process:point_ns/Point-v0", "--env-opt", f"python={sys.executable}")
    with EpisodeStore.open(tmp_path / "here.zarr") as here, EpisodeStore.open(tmp_path / "there.zarr") as there:
        assert list(there.meta.features) == list(here.meta.features)
        assert "obs.image_pixels_top" in there.meta.features  # the nested camera, read as a camera
        assert there.column("success").all() and list(there.column("seed")) == list(here.column("seed"))
        for i in range(3):
            a, b = here.read_episode(i), there.read_episode(i)
            for key in a:
                np.testing.assert_array_equal(b[key], a[key], err_msg=key)
        assert there.meta.task["options"]["python"] == sys.executable  # demo eval starts it again
    run = tmp_path / "run"
    assert main(["train", str(tmp_path / "there.zarr"), "--out", str(run), "--steps", "50", "--chunk", "4"]) == 0
    js = tmp_path / "eval.json"
    assert main(["eval", str(run), "--episodes", "2", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    assert result["task"] == "env:process:point_ns/Point-v0" and result["episodes"] == 2


def test_errors_come_back_in_one_line(point: Path, tmp_path: Path, one_line_error) -> None:
    out = tmp_path / "x.zarr"
    one_line_error(["collect", "--env", "process:point_ns/Point-v0", "--expert", "point_ns:expert", "--out", str(out)],
                   "--env-opt python=/path/to/venv/bin/python")
    one_line_error(["collect", "--env", "process:point_ns/Point-v0", "--env-opt", f"python={tmp_path / 'nope'}",
                    "--expert", "point_ns:expert", "--out", str(out)], "no such Python interpreter")
    one_line_error(["collect", "--env", "process:point_ns/Nowhere-v0", "--env-opt", f"python={sys.executable}",
                    "--expert", "point_ns:expert", "--out", str(out)], "--env process:point_ns/Nowhere-v0",
                   "NameNotFound")
    one_line_error(["collect", "--env", "process:point_ns/Point-v0", "--env-opt", f"python={sys.executable}",
                    "--env-opt", "speed=fast", "--expert", "point_ns:expert", "--episodes", "1", "--out", str(out)],
                   "TypeError")  # the environment's own exception, answered by the worker
    assert not out.exists()


def test_a_worker_that_dies_is_named_with_its_last_words(point: Path) -> None:
    env = ProcessEnv("point_ns/Point-v0", sys.executable)
    try:
        env.reset(seed=1)
        os.kill(env._proc.pid, signal.SIGKILL)
        with pytest.raises(DemoError) as err:
            env.step(np.zeros(2, np.float32))
        assert "ended (exit code -9)" in str(err.value) and "\n" not in str(err.value)
    finally:
        env.close()
