"""demo.sim: the built-in robot, task scenes, the gymnasium-style env and state-feedback experts.

    from demo.sim import RobotConfig, load_robot, make_env, TASK_NAMES
    env = make_env("pick", robot=None, cameras=(), **task_options)
    obs = env.reset(seed=3)
    expert = env.expert(rng)            # decides from the current simulator state only
    obs, reward, terminated, truncated, info = env.step(expert.act(env))

See :mod:`demo.sim.env` for the action/observation conventions, :mod:`demo.sim.scene` for frames,
:mod:`demo.sim.robot` for robot configs and :mod:`demo.sim.task` for what experts promise.
"""

import os

# Headless offscreen rendering; must be decided before mujoco is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

from demo.sim.env import Env, make_env  # noqa: E402
from demo.sim.robot import RobotConfig, load_robot  # noqa: E402
from demo.sim.task import Expert, Task  # noqa: E402
from demo.sim.tasks import TASK_NAMES, TASKS  # noqa: E402

__all__ = ["Env", "Expert", "RobotConfig", "Task", "TASKS", "TASK_NAMES", "load_robot", "make_env"]
