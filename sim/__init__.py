"""demo.sim: the built-in robot, task scenes, the gymnasium-style env and state-feedback experts.

    from demo.sim import RobotConfig, load_robot, make_env, TASK_NAMES
    env = make_env("pick", robot=None, cameras=(), **task_options)
    obs = env.reset(seed=3)
    expert = env.expert(rng)            # decides from the current simulator state only
    obs, reward, terminated, truncated, info = env.step(expert.act(env))

See :mod:`demo.sim.env` for the action/observation conventions, :mod:`demo.sim.scene` for frames,
:mod:`demo.sim.robot` for robot configs and :mod:`demo.sim.task` for what experts promise.

The names above are imported on first use: a module that needs only a part of demo.sim (`demo info`
reads a robot record) does not pay for the env, the tasks and gymnasium.
"""

import importlib
import os
from typing import Any

# Headless offscreen rendering; must be decided before mujoco is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

# The names `from demo.sim import ...` gives -> the module that defines each.
_DEFINED_IN = {"Env": "env", "make_env": "env", "RobotConfig": "robot", "load_robot": "robot", "Expert": "task",
               "Task": "task", "TASKS": "tasks", "TASK_NAMES": "tasks"}
__all__ = list(_DEFINED_IN)


def __getattr__(name: str) -> Any:
    if name not in _DEFINED_IN:
        raise AttributeError(f"module 'demo.sim' has no attribute {name!r}")
    return getattr(importlib.import_module(f"demo.sim.{_DEFINED_IN[name]}"), name)
