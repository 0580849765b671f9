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
one line naming it. Members are built when first selected (a Meta-World env takes a fraction of a second;
from a camera one to three seconds and ~170 MB for its renderer, so a caller that runs each member's
episodes together keeps one built at a time: :meth:`ForeignEnvSet.keep_at_most`, as ``demo eval`` does).
"""

from __future__ import annotations

import importlib
from collections import OrderedDict
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
        first = ForeignEnv(self.tasks[0], **self.options)
        self._members: OrderedDict[int, ForeignEnv] = OrderedDict({0: first})  # the built ones, least recent first
        self._max_live: int | None = None  # members kept built at once (None: every one)
        self._first_record = first.record()
        self.features, self.action_spec, self.cameras = first.features, first.action_spec, first.cameras
        self.fps, self.horizon = first.fps, first.horizon
        self.active = first

    def keep_at_most(self, n: int) -> None:
        """Keep at most ``n`` members built, closing the least recently selected beyond that. Why: from a camera
        each member holds a renderer, and all of MT50's in each of two evaluation workers took 8.9 GB apiece;
        a caller whose episodes go member by member (``demo eval``'s order) then builds each member once."""
        if n < 1:
            raise ValueError(f"keep at least one member built, got {n}")
        self._max_live = n
        self._close_beyond(n)

    def member(self, k: int) -> ForeignEnv:
        """Member ``k`` (built on first use; its features and action checked against the first member's)."""
        if k in self._members:
            self._members.move_to_end(k)
            return self._members[k]
        env = ForeignEnv(self.tasks[k], **self.options)
        if env.features != self.features or env.action_spec != self.action_spec:
            env.close()
            raise DemoError(f"--env {self.name.removeprefix(ENV_PREFIX)}",
                            f"member {env.name} records other features or another action than "
                            f"{self.tasks[0]}; a set's members must share their spaces")
        self._members[k] = env
        if self._max_live is not None:
            self._close_beyond(self._max_live)
        return env

    def built(self) -> list[int]:
        """The members built now, least recently selected first."""
        return list(self._members)

    def _close_beyond(self, n: int) -> None:
        while len(self._members) > n:
            _, env = self._members.popitem(last=False)
            env.close()

    def member_of(self, index: int) -> int:
        """Which member episode ``index`` runs in: the set's tasks in turn."""
        return index % len(self.tasks)

    def select(self, index: int) -> ForeignEnv:
        """The member that episode ``index`` runs in (:meth:`member_of`), now the active one."""
        self.active = self.member(self.member_of(index))
        return self.active

    def record(self) -> dict[str, Any]:
        """What a store and a run say of the set: the first member's record, with the set's name and members."""
        return {**self._first_record, "name": self.name.removeprefix(ENV_PREFIX), "id": None,
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
