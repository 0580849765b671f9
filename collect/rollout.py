"""One episode in the simulator, recorded frame by frame: the loop shared by collection, DAgger and eval.

Frame ``t`` holds the state *before* the command of step ``t`` is executed: ``obs.*`` and
``sim.state`` from ``env.frame()``, then ``action`` (the label), ``info.executed_action`` (what was
actually sent, which differs under DART noise or a learner in control) and ``info.ee_target`` (the
end-effector target behind the command, when there is one).

An episode ends at the task horizon, or once success has held for ``hold_success_s`` seconds so that
the demonstrations end in a settled, successful state rather than at the first instant of success.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from demo.store import FeatureSpec


class StepCommand(NamedTuple):
    executed: np.ndarray  # sent to env.step, in env.action_spec
    label: np.ndarray  # recorded as the action (the expert's answer, or == executed)
    ee_target: np.ndarray | None = None  # (7,) pos (m, base frame) + quat wxyz, if known


class Env(Protocol):  # the part of demo.sim's environment a rollout uses
    fps: float
    horizon: int

    def reset(self, seed: int) -> dict[str, np.ndarray]: ...
    def frame(self, obs: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]: ...
    def step(self, action: np.ndarray) -> tuple: ...
    def success(self) -> bool: ...


Actor = Callable[[Any, dict[str, np.ndarray], int], StepCommand]


@dataclass
class Episode:
    data: dict[str, np.ndarray]
    success: bool
    length: int
    first_success_step: int | None
    info: dict[str, Any] = field(default_factory=dict)


def recorded_features(env: Any) -> dict[str, FeatureSpec]:
    """Every per-frame key a recorded episode has, besides ``action``."""
    action = env.action_spec
    return {
        **env.features,
        "info.executed_action": FeatureSpec(
            (action.dim,), "float32", f"command actually executed ({action.name})", ",".join(action.units), action.names
        ),
        "info.ee_target": FeatureSpec(
            (7,), "float32", "end-effector target behind the command: position + quaternion wxyz, base frame", "m,1"
        ),
    }


def rollout(
    env: Any,
    seed: int,
    actor: Actor,
    *,
    max_steps: int | None = None,
    hold_success_s: float = 0.5,
    record: bool = True,
    reset: bool = True,
) -> Episode:
    """Run ``actor`` from ``env.reset(seed)`` and return the recorded episode."""
    if reset:
        env.reset(seed)
    horizon = max_steps or env.horizon
    hold_steps = int(round(hold_success_s * env.fps))
    frames: dict[str, list[np.ndarray]] = {}
    unknown_target = np.zeros(7, dtype=np.float32)  # a zero quaternion marks "no target known"
    first_success: int | None = None
    streak_start: int | None = None
    steps = 0
    frame = env.frame()
    for t in range(horizon):
        command = actor(env, frame, t)
        if record:
            frame = dict(frame)
            frame["action"] = command.label
            frame["info.executed_action"] = command.executed
            frame["info.ee_target"] = unknown_target if command.ee_target is None else command.ee_target
            for key, value in frame.items():
                frames.setdefault(key, []).append(np.asarray(value))
        obs, _, success, _, _ = env.step(command.executed)
        steps = t + 1
        frame = env.frame(obs)
        if success:
            first_success = t + 1 if first_success is None else first_success
            streak_start = t + 1 if streak_start is None else streak_start
            if steps - streak_start >= hold_steps:
                break
        else:
            streak_start = None
    data = {k: np.stack(v) for k, v in frames.items()} if record else {}
    return Episode(data=data, success=bool(env.success()), length=steps, first_success_step=first_success)
