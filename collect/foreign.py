"""Experts for foreign environments (:mod:`demo.sim.foreign`): ``demo collect --env ENV --expert EXPERT``.

EXPERT is ``module:callable``, called at every step as ``callable(obs, env) -> action`` with the
environment's own observation and the ``gymnasium.Env`` (for an expert that needs privileged state);
or, where the callable takes ``env`` alone and returns an object with ``act(obs)``, a new expert per
episode (``callable(env)`` right after each reset). Named adapters' experts:

- ``demo``: the scripted expert of a ``demo/<Task>-v0`` environment (``env.unwrapped.expert()``);
- ``metaworld``: Meta-World's scripted policy of the task (:mod:`demo.sim.metaworld`).

An expert that raises, or returns an action of the wrong shape or with a non-finite value, stops the
collection with one line naming it; the episodes committed before stay stored.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.sim import metaworld
from demo.sim.foreign import ForeignEnv
from demo.sim.rollout import StepCommand, rollout

StepExpert = Callable[[Any], np.ndarray]  # observation -> action, for one episode


def _demo_expert(env: Any) -> Any:
    return env.unwrapped.expert()


NAMED_EXPERTS: dict[str, Callable[[Any], Any]] = {"demo": _demo_expert, "metaworld": metaworld.expert}


def load_expert(name: str) -> Callable[[Any], StepExpert]:
    """The expert ``name`` as a per-episode factory: ``factory(gym_env)`` after each reset gives the
    episode's ``observation -> action`` function."""
    where = f"--expert {name}"
    if name in NAMED_EXPERTS:
        per_episode = NAMED_EXPERTS[name]
        return lambda env: per_episode(env).act
    module, sep, attr = name.partition(":")
    if not sep or not module or not attr:
        raise DemoError(where, f"is not module:callable nor a named expert ({', '.join(NAMED_EXPERTS)})")
    try:
        found = getattr(importlib.import_module(module), attr)
    except ImportError as exc:
        raise DemoError(where, f"cannot import {module!r} ({exc})") from None
    except AttributeError:
        raise DemoError(where, f"{module} has no {attr!r}") from None
    if not callable(found):
        raise DemoError(where, f"{attr} is not callable")
    try:
        takes = len(inspect.signature(found).parameters)
    except (TypeError, ValueError):
        takes = 2
    if takes == 1:  # a factory of per-episode experts
        return lambda env: getattr(found(env), "act")
    return lambda env: (lambda obs: found(obs, env))


def checked_action(expert: str, action: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``action`` as float32 of ``shape``, or a one-line error naming the expert."""
    try:
        a = np.asarray(action, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise DemoError(f"--expert {expert}", f"returned {type(action).__name__}, not an action ({exc})") from None
    if a.shape != shape:
        raise DemoError(f"--expert {expert}", f"returned an action of shape {a.shape}; the environment takes {shape}")
    if not np.isfinite(a).all():
        raise DemoError(f"--expert {expert}", "returned a non-finite action")
    return a


class ForeignExpert:
    """One episode's expert in a foreign environment, asked as the tasks' experts are: ``act(env)`` is its
    checked action in whatever state ``env`` is in now (it reads ``env.raw_obs``), so DAgger can label the
    states a learner drives to. Made right after ``env.reset``; ``ee_target`` is unknown (None)."""

    ee_target = None

    def __init__(self, name: str, env: ForeignEnv):
        self.name, self.shape, self.t = name, env.gym.action_space.shape, 0
        factory = load_expert(name)  # a bad name fails here, in its own words
        try:
            self.policy = factory(env.gym)
        except Exception as exc:  # noqa: BLE001 - the user's code: any failure becomes one line naming it
            raise DemoError(f"--expert {name}", f"raised {type(exc).__name__}: {exc}") from None

    def act(self, env: ForeignEnv) -> np.ndarray:
        try:
            action = self.policy(env.raw_obs)
        except Exception as exc:  # noqa: BLE001 - as above
            raise DemoError(f"--expert {self.name}", f"raised {type(exc).__name__} at step {self.t}: {exc}") from None
        self.t += 1
        return checked_action(self.name, action, self.shape)


def foreign_episode(env: ForeignEnv, expert: str, seed: int, noise: float = 0.0, instruction: str | None = None
                    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One episode of ``expert`` (a name :func:`load_expert` takes) in the foreign environment ``env``
    from ``env.reset(seed)``; ``noise``: std of Gaussian noise on every executed action dimension (DART;
    the recorded label stays the expert's); ``instruction``: what the episode was told (None: the
    environment's own, if any)."""
    rng = np.random.default_rng([seed, 1])
    env.reset(seed)
    policy = ForeignExpert(expert, env)

    def act(env: ForeignEnv, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        label = policy.act(env)
        executed = label + rng.normal(0.0, noise, label.shape).astype(np.float32) if noise > 0 else label
        return StepCommand(executed=executed, label=label)

    episode = rollout(env, seed, act, reset=False)
    info: dict[str, Any] = {
        "success": episode.success,
        "seed": seed,
        "source": "scripted",
        "operator": "expert",
        "task": env.name,
        "noise": float(noise),
        "expert_mode": "",
        "first_success_step": -1 if episode.first_success_step is None else episode.first_success_step,
    }
    told = instruction or env.instruction
    if told:
        info["instruction"] = told
    return episode.data, info
