"""From the policy's action representation to the environment's.

A policy outputs actions in the representation of the store it was trained on (``joint_pos``,
``ee7``, ...). When that is what the environment takes (``env.action_spec``), actions pass through
unchanged. Otherwise :func:`demo.convert.adapter.make_adapter` provides the adapter: an object with
``reset(env)`` (called after every ``env.reset``, e.g. to anchor end-effector deltas) and
``__call__(action) -> env action`` (e.g. IK each step for an ``ee7`` policy).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from demo.convert.adapter import make_adapter
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
        return make_adapter(spec, env)
    except DemoError:
        raise
    except (KeyError, ValueError, NotImplementedError) as exc:
        raise DemoError(where, f"cannot execute {spec.name!r} actions on this environment: {exc}") from None
