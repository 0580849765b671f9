"""Any Gymnasium environment as a task: a source of demonstrations and a judge of policies.

A foreign environment is named by its Gymnasium id (``CartPole-v1``, ``demo/Reach-v0``; a
``module:`` prefix imports the module that registers it first, ``mypkg.envs:MyEnv-v0``), by a
factory, ``module:function`` returning a ``gymnasium.Env``, or through a named adapter,
``ADAPTER:TASK`` (:data:`ADAPTERS`: ``metaworld:pick-place-v3``, :mod:`demo.sim.metaworld`;
``process:NAME`` with ``python=PYTHON``, any of these run by another interpreter, :mod:`demo.sim.process_env`),
with keyword arguments in every case. Its
task name in a store or a run is ``env:<name>`` and its keyword arguments are the task options, so
:func:`demo.sim.make_env` rebuilds it and ``demo eval RUN`` needs no flag to find it again.

:class:`ForeignEnv` gives it the interface the rollout loop, collection, training and evaluation
share with the tasks' :class:`demo.sim.env.Env`:

- **features from the spaces**: a ``Box`` observation is ``obs.state``; a ``Dict`` is flattened,
  ``obs.<key>`` per entry (``obs.`` kept where the key has it; nested keys joined by ``_``); a
  ``uint8`` ``Box`` of shape ``(H, W, 3)`` is a camera, ``obs.image_<key>``. Other spaces are refused.
- **the action** is the action space's ``Box`` (float32), representation ``env`` (the environment's
  own command: nothing in :mod:`demo.convert` re-expresses it).
- **success is the environment's own signal**, never recomputed: ``info["success"]`` or
  ``info["is_success"]`` after each step (a number counts as success when > 0).
- **seeds**: ``reset(seed)`` is ``env.reset(seed=seed)``, one to one: the store's ``seed`` column is
  what the environment was reset with, so another tool can start from the same states.
- **the end of an episode**: the environment's ``terminated`` or ``truncated``, its first success
  (success is judged when it first holds: the benchmark convention), or the horizon: the env's
  ``max_episode_steps``, else its ``horizon`` attribute (``--env-opt max_episode_steps=N`` where it has neither).
- ``fps``: ``metadata["render_fps"]``, else 10 (it only times videos and the success hold).

Spaces are checked at every reset and step: an observation that no longer matches the features
the episode started with fails with one line naming the key.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import Any

import gymnasium
import numpy as np

from demo.errors import DemoError
from demo.store import ActionSpec, FeatureSpec
from demo.store.instructions import normalized

ENV_PREFIX = "env:"  # a store's task name for a foreign environment: env:<id or module:factory>
ACTION_NAME = "env"  # the action representation: the environment's own command
DEFAULT_FPS = 10.0
HORIZON_OPTION = "max_episode_steps"
# Named adapters: ``--env NAME:TASK`` builds TASK with the adapter's own factory (a benchmark that needs
# more than gymnasium.make: a compatibility fix, its task sets, its experts).
ADAPTERS = {"metaworld": "demo.sim.metaworld:make", "process": "demo.sim.process_env:make"}


def is_foreign(task: str | None) -> bool:
    """Whether a task name names a foreign environment (``env:...``)."""
    return bool(task) and str(task).startswith(ENV_PREFIX)


def task_name(env: str) -> str:
    """The task name a store records for the environment ``env`` (``CartPole-v1`` -> ``env:CartPole-v1``)."""
    return env if is_foreign(env) else ENV_PREFIX + env


def _strings(value: Any, n: int) -> bool:
    """Whether ``value`` is ``n`` non-empty strings."""
    return isinstance(value, (list, tuple)) and len(value) == n and all(isinstance(v, str) and v for v in value)


def success_of(info: Any) -> bool:
    """The environment's own success flag in a step's ``info`` (``success``, else ``is_success``; a number
    counts when > 0)."""
    flag = info.get("success", info.get("is_success", False)) if isinstance(info, dict) else False
    return bool(float(flag) > 0)


def make_gym(name: str, options: dict[str, Any]) -> gymnasium.Env:
    """The Gymnasium environment ``name`` (an id, ``module:id``, ``module:factory`` or ``ADAPTER:TASK``) built with
    ``options``."""
    name = name.removeprefix(ENV_PREFIX)
    named, _, inner = name.partition(":")  # an adapter takes the rest of the name as it is (process:mod:id)
    if named in ADAPTERS:
        adapter, _, function = ADAPTERS[named].partition(":")
        return getattr(importlib.import_module(adapter), function)(inner, **options)
    module, sep, attr = name.rpartition(":")
    where = f"--env {name}"
    if sep:
        try:
            mod = importlib.import_module(module)
        except ImportError as exc:
            raise DemoError(where, f"cannot import {module!r} ({exc}); is its package installed?") from None
        factory = getattr(mod, attr, None)
        if callable(factory) and attr not in gymnasium.registry:
            try:
                env = factory(**options)
            except TypeError as exc:
                raise DemoError(where, f"{attr}({', '.join(f'{k}=...' for k in options)}) failed: {exc}") from None
            if not isinstance(env, gymnasium.Env):
                raise DemoError(where, f"{attr} returned a {type(env).__name__}, not a gymnasium.Env")
            return env
        name = attr
    if name not in gymnasium.registry:
        near = [k for k in gymnasium.registry if k.lower().startswith(name.split("-")[0].lower()[:4])][:5]
        hint = f"; similar: {', '.join(near)}" if near else ""
        raise DemoError(where, f"no Gymnasium environment {name!r} is registered (a module:function factory, or "
                               f"module:id to import the package that registers it){hint}")
    try:
        return gymnasium.make(name, **options)
    except TypeError as exc:
        raise DemoError(where, f"cannot be made with {options}: {exc}") from None


def instruction_of(name: str, env: gymnasium.Env) -> str:
    """What the environment asks for in words: its own ``instruction`` attribute (a user's environment),
    else its adapter's ``instruction(TASK)`` (Meta-World's task as a sentence); "" when neither says."""
    own = getattr(env.unwrapped, "instruction", None)
    if isinstance(own, str) and own.strip():
        return normalized(own)
    module, _, task = name.removeprefix(ENV_PREFIX).partition(":")
    if module in ADAPTERS:
        described = getattr(importlib.import_module(ADAPTERS[module].partition(":")[0]), "instruction", None)
        if callable(described):
            return str(described(task))
    return ""


def flatten_space(space: gymnasium.Space, where: str) -> dict[str, tuple[str, gymnasium.spaces.Box]]:
    """Feature name -> (path in the observation, Box) for every leaf of an observation space."""
    out: dict[str, tuple[str, gymnasium.spaces.Box]] = {}

    def visit(s: gymnasium.Space, path: tuple[str, ...]) -> None:
        if isinstance(s, gymnasium.spaces.Dict):
            for key, sub in s.spaces.items():
                visit(sub, (*path, str(key)))
            return
        if not isinstance(s, gymnasium.spaces.Box):
            raise DemoError(where, f"observation {'/'.join(path) or '(root)'} is a {type(s).__name__} space; "
                                   "only Box and Dict observations are recorded")
        key = "_".join(path) if path else "state"
        if s.dtype == np.uint8 and len(s.shape) == 3 and s.shape[-1] == 3:
            name = f"obs.image_{key.removeprefix('obs.').removeprefix('image_')}"
        else:
            name = key if key.startswith("obs.") else f"obs.{key}"
        out[name] = ("/".join(path), s)

    visit(space, ())
    return out


def _bound(values: np.ndarray) -> list[float] | None:
    return [float(v) for v in values.ravel()] if np.all(np.isfinite(values)) else None


def package_versions(env: gymnasium.Env) -> dict[str, str]:
    """The versions of the packages that define ``env`` (its class's top-level package, gymnasium)."""
    out = {"gymnasium": gymnasium.__version__}
    top = type(env.unwrapped).__module__.split(".")[0]
    for dist in importlib.metadata.packages_distributions().get(top, [top]):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            pass
    return out


class ForeignTask:
    """What the rollout loop asks of a task: a foreign environment has no failure of its own."""

    name = "foreign"

    def failure(self, env: Any) -> None:
        return None


class ForeignEnv:
    """A Gymnasium environment behind the tasks' environment interface (module docstring)."""

    ends_episodes = True  # the rollout loop ends an episode when step() says it ended (module docstring)
    robot = None

    def __init__(self, name: str, **options: Any):
        self.name = task_name(name)
        self.options = dict(options)
        gym_options = {k: v for k, v in options.items() if k != HORIZON_OPTION}
        self.gym = make_gym(name, gym_options)
        self.task = ForeignTask()
        where = f"--env {self.name.removeprefix(ENV_PREFIX)}"
        self.where = where
        self.leaves = flatten_space(self.gym.observation_space, where)
        # The spec's limit, else the environment's own horizon attribute (demo's tasks: it depends on their options)
        limit = (options.get(HORIZON_OPTION) or getattr(self.gym.spec, "max_episode_steps", None)
                 or getattr(self.gym.unwrapped, "horizon", None))
        if not limit:
            raise DemoError(where, f"has no episode limit: pass --env-opt {HORIZON_OPTION}=N")
        self.horizon = int(limit)
        self.fps = float((self.gym.metadata or {}).get("render_fps") or DEFAULT_FPS)
        self.action_spec = self._action_spec()
        self.features = {name: self._feature(name, box) for name, (_, box) in self.leaves.items()}
        self.cameras = [name for name in self.features if name.startswith("obs.image_")]
        self._obs: dict[str, np.ndarray] = {}
        self.raw_obs: Any = None
        self._success = False
        self._steps = 0
        self.seed: int | None = None

    # ------------------------------------------------------------------ what a store records
    def _action_spec(self) -> ActionSpec:
        space = self.gym.action_space
        if not isinstance(space, gymnasium.spaces.Box) or len(space.shape) != 1:
            raise DemoError(self.where, f"its action space is {space}; only a 1-D Box is recorded")
        n = int(space.shape[0])
        # An environment may name its action's dimensions and units (``action_names``, ``action_units``)
        names, units = (getattr(self.gym.unwrapped, k, None) for k in ("action_names", "action_units"))
        if not _strings(names, n) or len(set(names)) != n:
            names = tuple(f"a{i}" for i in range(n))
        if not _strings(units, n):
            units = ("1",) * n
        return ActionSpec(ACTION_NAME, tuple(names), tuple(units), frame="env",
                          description="the environment's own command",
                          params={"low": _bound(space.low), "high": _bound(space.high)})

    def _feature(self, name: str, box: gymnasium.spaces.Box) -> FeatureSpec:
        if name.startswith("obs.image_"):
            return FeatureSpec(tuple(box.shape), "uint8", "camera image (RGB)", "")
        return FeatureSpec((int(np.prod(box.shape)),), "float32", "observation", "")

    def record(self) -> dict[str, Any]:
        """What a store and a run say of the environment: its name, options and defining packages."""
        spec = self.gym.spec
        return {"name": self.name.removeprefix(ENV_PREFIX), "options": self.options,
                "id": getattr(spec, "id", None), "entry_point": str(getattr(spec, "entry_point", "") or ""),
                "packages": package_versions(self.gym)}

    # ------------------------------------------------------------------ the episode API
    def frame_of(self, obs: Any) -> dict[str, np.ndarray]:
        """The environment's observation ``obs`` as a frame of features (checked against the spaces)."""
        out = {}
        for name, (path, box) in self.leaves.items():
            value = obs
            for key in path.split("/") if path else ():
                if not isinstance(value, dict) or key not in value:
                    raise DemoError(self.where, f"observation has no {path!r} (its space changed after reset)")
                value = value[key]
            array = np.asarray(value)
            if array.shape != box.shape:
                raise DemoError(self.where, f"observation {name} has shape {array.shape}, its space says {box.shape}")
            out[name] = array.astype(np.uint8) if name.startswith("obs.image_") else \
                array.astype(np.float32).reshape(-1)
        return out

    def reset(self, seed: int) -> dict[str, np.ndarray]:
        self.seed = int(seed)
        obs, _ = self.gym.reset(seed=self.seed)
        self.raw_obs = obs  # what the environment returned, for an expert that reads it as it is
        self._obs, self._success, self._steps = self.frame_of(obs), False, 0
        return self._obs

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        a = np.asarray(action, dtype=self.gym.action_space.dtype)
        if a.shape != self.gym.action_space.shape:
            raise DemoError("action", f"expected shape {self.gym.action_space.shape}, got {a.shape}")
        obs, reward, terminated, truncated, info = self.gym.step(a)
        self.raw_obs = obs
        self._steps += 1
        self._obs = self.frame_of(obs)
        self._success = success_of(info)
        ended = bool(terminated or truncated or self._success or self._steps >= self.horizon)
        return self._obs, float(reward), self._success, ended, info

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def instruction(self) -> str:
        """What the environment asks for now, in words (it may change at each reset; :func:`instruction_of`)."""
        return instruction_of(self.name, self.gym)

    def success(self) -> bool:
        return self._success

    def observe(self) -> dict[str, np.ndarray]:
        return dict(self._obs)

    def frame(self, obs: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The observations (a foreign environment has no simulator state to record)."""
        return dict(self._obs if obs is None else obs)

    def close(self) -> None:
        self.gym.close()
