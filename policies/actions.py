"""From the policy's action representation to the environment's.

A policy outputs actions in the representation of the store it was trained on (``joint_pos``,
``ee7``, ...). When that is what the environment takes (``env.action_spec``), actions pass through
unchanged. Otherwise :mod:`demo.convert.adapter` provides the adapter: an object with
``reset(env)`` (called after every ``env.reset``, e.g. to anchor end-effector deltas) and
``__call__(action) -> env action`` (e.g. IK each step for an ``ee7`` policy).

Expected there: ``make_adapter(spec: demo.store.ActionSpec, env) -> adapter``.
"""

from __future__ import annotations

import importlib
from typing import Any, Protocol

import numpy as np

from demo.errors import DemoError
from demo.store import ActionSpec


class ActionAdapter(Protocol):
    def reset(self, env: Any) -> None: ...
    def __call__(self, action: np.ndarray) -> np.ndarray: ...


def make_action_adapter(spec: ActionSpec, env: Any, where: str = "run") -> ActionAdapter | None:
    """``None`` when the policy's actions are already the environment's, else an adapter."""
    env_spec = env.action_spec
    if spec.name == env_spec.name:
        if spec.dim != env_spec.dim:
            raise DemoError(
                where, f"policy outputs {spec.dim} {spec.name} values; the environment takes {env_spec.dim}"
            )
        return None
    try:
        module = importlib.import_module("demo.convert.adapter")
    except ModuleNotFoundError:
        module = None
    if module is None or not hasattr(module, "make_adapter"):
        raise DemoError(
            where,
            f"policy outputs {spec.name!r} actions and the environment takes {env_spec.name!r}; "
            "no action adapter is available (demo.convert.adapter)",
        )
    try:
        return module.make_adapter(spec, env)
    except DemoError:
        raise
    except (KeyError, ValueError, NotImplementedError) as exc:
        raise DemoError(where, f"cannot execute {spec.name!r} actions on this environment: {exc}") from None
