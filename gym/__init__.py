"""The tasks as Gymnasium environments: ``import demo.gym`` registers ``demo/<Task>-v0`` for every task
of the task registry (:data:`demo.sim.tasks.TASKS`): ``demo/Reach-v0``, ``demo/Pick-v0``, ...

    import gymnasium
    import demo.gym
    from demo.seeds import episode_seed

    env = gymnasium.make("demo/Pick-v0", cameras=["front@64x64"], action="ee7")
    obs, info = env.reset(seed=episode_seed(0, 3))  # the start of episode 3 of `demo collect --seed 0`
    expert = env.unwrapped.expert()
    obs, reward, terminated, truncated, info = env.step(expert.act(obs))

Options, spaces, seeds, reward and the end of an episode: :class:`demo.gym.env.DemoEnv`.
"""

from __future__ import annotations

import gymnasium

from demo.gym.env import DemoEnv
from demo.gym.expert import GymExpert, ObservationExpert
from demo.sim.tasks import TASK_NAMES

ENTRY_POINT = "demo.gym.env:DemoEnv"


def env_id(task: str) -> str:
    """The registered id of a task: ``pick`` -> ``demo/Pick-v0``."""
    return f"demo/{task.capitalize()}-v0"


ENV_IDS: dict[str, str] = {task: env_id(task) for task in TASK_NAMES}


def register_all() -> None:
    """Register every task once (importing this module does it; a second call changes nothing)."""
    for task, name in ENV_IDS.items():
        if name not in gymnasium.registry:
            gymnasium.register(id=name, entry_point=ENTRY_POINT, kwargs={"task": task})


register_all()

__all__ = ["DemoEnv", "ENV_IDS", "GymExpert", "ObservationExpert", "env_id", "register_all"]
