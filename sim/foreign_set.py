"""A named adapter's task set as one environment: ``--env metaworld:MT10`` collects and judges every task.

A set (``ADAPTER:SET``, where the adapter module has ``task_set(SET) -> [task, ...]``: Meta-World's
``MT10`` and ``MT50``) is one :class:`ForeignEnvSet` whose members are the tasks'
:class:`~demo.sim.foreign.ForeignEnv`. Episode ``i`` runs in member ``i % n`` (:meth:`ForeignEnvSet.select`),
so the tasks interleave: ``--episodes N`` gives each task ``N`` episodes (``N * n`` in all), and a
store cut short holds every task about equally. The seed column stays what the member was reset with
(one to one, as for one environment) and the episode's ``task`` column names the member
(``env:metaworld:reach-v3``); the store's task is the set (``env:metaworld:MT10``), which ``demo eval``
rebuilds to judge a run on every member, with a per-task table.

Every member must record the same features and action as the first; one that does not is refused in
one line naming it. Members are built when first selected (a Meta-World env takes a fraction of a second).
"""

from __future__ import annotations

import importlib
from typing import Any

from demo.errors import DemoError
from demo.sim.foreign import ADAPTERS, ENV_PREFIX, ForeignEnv


def set_members(name: str) -> list[str] | None:
    """The member environments of a task set (``metaworld:MT10`` -> ``['metaworld:reach-v3', ...]``), or None
    when ``name`` is not a set (a named adapter's ``task_set`` returns more than the name itself)."""
    adapter, sep, which = name.removeprefix(ENV_PREFIX).partition(":")
    if not sep or adapter not in ADAPTERS:
        return None
    module = importlib.import_module(ADAPTERS[adapter].partition(":")[0])
    task_set = getattr(module, "task_set", None)
    if task_set is None:
        return None
    tasks = task_set(which)
    return [f"{adapter}:{t}" for t in tasks] if tasks != [which] else None


class ForeignEnvSet:
    """Several foreign environments with the same spaces, one per episode (module docstring)."""

    ends_episodes = True
    robot = None

    def __init__(self, name: str, members: list[str], **options: Any):
        self.name = ENV_PREFIX + name.removeprefix(ENV_PREFIX)
        self.options = dict(options)
        self.tasks = [ENV_PREFIX + m for m in members]
        self._members: dict[int, ForeignEnv] = {}
        first = self.member(0)
        self.features, self.action_spec, self.cameras = first.features, first.action_spec, first.cameras
        self.fps, self.horizon = first.fps, first.horizon
        self.active = first

    def member(self, k: int) -> ForeignEnv:
        """Member ``k`` (built on first use; its features and action checked against the first member's)."""
        if k not in self._members:
            env = ForeignEnv(self.tasks[k], **self.options)
            if self._members:
                first = self._members[0]
                if env.features != first.features or env.action_spec != first.action_spec:
                    env.close()
                    raise DemoError(f"--env {self.name.removeprefix(ENV_PREFIX)}",
                                    f"member {env.name} records other features or another action than "
                                    f"{first.name}; a set's members must share their spaces")
            self._members[k] = env
        return self._members[k]

    def select(self, index: int) -> ForeignEnv:
        """The member that episode ``index`` runs in (``index % n``), now the active one."""
        self.active = self.member(index % len(self.tasks))
        return self.active

    def record(self) -> dict[str, Any]:
        """What a store and a run say of the set: the first member's record, with the set's name and members."""
        return {**self.member(0).record(), "name": self.name.removeprefix(ENV_PREFIX), "id": None,
                "tasks": [t.removeprefix(ENV_PREFIX) for t in self.tasks]}

    # The episode API is the active member's (select() first).
    def reset(self, seed: int) -> Any:
        return self.active.reset(seed)

    def step(self, action: Any) -> Any:
        return self.active.step(action)

    @property
    def steps(self) -> int:
        return self.active.steps

    def success(self) -> bool:
        return self.active.success()

    def observe(self) -> Any:
        return self.active.observe()

    def frame(self, obs: Any = None) -> Any:
        return self.active.frame(obs)

    @property
    def task(self) -> Any:
        return self.active.task

    @property
    def instruction(self) -> str:
        return self.active.instruction

    def close(self) -> None:
        for env in self._members.values():
            env.close()
