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

DICT_POINT = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np
    from point_reach import PointReach


    class DictPoint(PointReach):
        """conftest's PointReach observed as gym-aloha observes: a Dict with a nested camera; a numpy scalar in
        its info."""

        def __init__(self, speed=0.05):
            super().__init__(speed)
            self.observation_space = gym.spaces.Dict({
                "agent_pos": gym.spaces.Box(-1.0, 1.0, (2,), np.float64),
                "goal": gym.spaces.Box(-1.0, 1.0, (2,), np.float64),
                "pixels": gym.spaces.Dict({"top": gym.spaces.Box(0, 255, (8, 8, 3), np.uint8)}),
            })

        def step(self, action):
            obs, reward, terminated, truncated, info = super().step(action)
            return obs, reward, terminated, truncated, {**info, "distance": np.float32(np.linalg.norm(self.pos - self.goal))}

        def _obs(self):
            image = np.zeros((8, 8, 3), np.uint8)
            image[int((self.pos[1] + 1) * 3.5), int((self.pos[0] + 1) * 3.5)] = 255
            return {"agent_pos": self.pos.copy(), "goal": self.goal.copy(), "pixels": {"top": image}}


    def expert(obs, env):
        return np.clip((obs["goal"] - obs["agent_pos"]) / 0.05, -1.0, 1.0)


    gym.register("point_ns/Point-v0", entry_point=DictPoint, max_episode_steps=60)
''')


@pytest.fixture
def point(user_module: str, tmp_path: Path) -> Path:
    """The environment as a user's package ``point_ns`` (registering ``point_ns/Point-v0`` on import) beside
    conftest's ``point_reach``, on the path of this process and of the worker it starts."""
    package = tmp_path / "user" / "point_ns"
    package.mkdir()
    (package / "__init__.py").write_text(DICT_POINT)
    yield package
    sys.modules.pop("point_ns", None)


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


def test_an_environment_that_names_its_action_dimensions_is_recorded_so(point: Path, tmp_path: Path) -> None:
    """``action_names`` / ``action_units`` on the unwrapped environment travel through the worker into the store."""
    named = point.parent / "named_point.py"
    named.write_text(textwrap.dedent('''
        from point_ns import DictPoint


        def make():
            env = DictPoint()
            env.action_names, env.action_units = ("dx", "dy"), ("m", "m")
            env.horizon = 60
            return env
    '''))
    try:
        collect(tmp_path / "named.zarr", "process:named_point:make", "--env-opt", f"python={sys.executable}")
        with EpisodeStore.open(tmp_path / "named.zarr") as store:
            assert store.meta.action.names == ("dx", "dy") and store.meta.action.units == ("m", "m")
    finally:
        sys.modules.pop("named_point", None)
