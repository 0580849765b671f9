"""The task registry: name -> Task class (each task and its expert live in one module)."""

from __future__ import annotations

from demo.sim.avoid import Avoid
from demo.sim.pick import Pick
from demo.sim.place import Place
from demo.sim.push import Push
from demo.sim.reach import Reach
from demo.sim.stack import Stack
from demo.sim.task import Task

TASKS: dict[str, type[Task]] = {t.name: t for t in (Reach, Pick, Push, Avoid, Stack, Place)}
TASK_NAMES: tuple[str, ...] = tuple(TASKS)
