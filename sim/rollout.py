"""One episode in the simulator: the loop collection, evaluation, DAgger and the expert checks share.

An *actor* answers each control step ``t`` with a :class:`StepCommand`: what is executed and what
is recorded as the action (they differ under DART noise or with a learner in control).

When an episode ends (the one rule, whoever acts):

- at the horizon: ``max_steps`` control steps, by default the task's ``env.horizon``; or
- once success has held for ``hold_success_s`` (default 0.5 s, 10 steps at 20 Hz): success is
  judged after every step; the episode ends ``hold_success_s * fps`` steps after the step at which
  it became true, if it stayed true after each of them (a step without it restarts the count), so
  that demonstrations end in a settled, successful state rather than at the first instant of
  success. ``hold_success_s = 0`` ends at the first success, ``None`` never ends early.
- A task's failure (``Task.failure``, e.g. avoid's ``"collision"``) does *not* end the episode:
  it is reported in :attr:`Episode.failure`. Collected failures have always been recorded to the
  horizon (curation decides what to keep), and ending them early would change collected stores.

Results: ``length`` is the number of control steps run; ``first_success_step`` the number of
steps after which success first held (1-based, the stores' ``first_success_step`` column; None if
never); ``success`` whether it holds after the last step; ``failure`` the task's failure then.

Recording (``record=True``): frame ``t`` holds the state *before* the command of step ``t`` is
executed: ``obs.*`` and ``sim.state`` from ``env.frame()``, then ``action`` (the label),
``info.executed_action`` (what was actually sent) and ``info.ee_target`` (the end-effector target
behind the command, position in m in the base frame + quaternion wxyz, when there is one; all zeros,
an impossible quaternion, when not).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from demo.sim.env import Env
from demo.sim.foreign import ForeignEnv
from demo.sim.foreign_set import ForeignEnvSet
from demo.sim.robot_record import robot_record
from demo.store import FeatureSpec, StoreMeta


class StepCommand(NamedTuple):
    executed: np.ndarray  # sent to env.step, in env.action_spec
    label: np.ndarray  # recorded as the action (the expert's answer, or == executed)
    ee_target: np.ndarray | None = None  # (7,) pos (m, base frame) + quat wxyz, if known


# actor(env, frame, t): the command of control step t, given the frame before it (env.frame()).
Actor = Callable[[Env, dict[str, np.ndarray], int], StepCommand]


@dataclass
class Episode:
    data: dict[str, np.ndarray]  # per-frame arrays [T, ...] when recorded, else empty
    success: bool  # the success predicate after the last step
    length: int  # control steps run
    first_success_step: int | None  # steps run when success first held (1-based); None if never
    failure: str | None = None  # the task's failure after the last step (e.g. "collision")


HOLD_SUCCESS_S = 0.5  # s: how long success must hold before an episode ends (module docstring)


class SuccessHold:
    """The success half of the ending rule (module docstring), fed one step at a time: after each
    control step, :meth:`update` with whether success holds; it answers True once success has held
    ``hold_success_s`` (s) at ``fps`` (Hz). The rollout loop and :mod:`demo.gym` share it, so an
    episode ends at the same step whoever runs it."""

    def __init__(self, hold_success_s: float | None, fps: float):
        self.hold_steps = None if hold_success_s is None else int(round(hold_success_s * fps))
        self.reset()

    def reset(self) -> None:
        self.steps = 0
        self.first_success: int | None = None  # steps run when success first held (1-based)
        self._streak_start: int | None = None

    def update(self, success: bool) -> bool:
        """Count one control step; True when the episode ends here by success."""
        self.steps += 1
        if not success:
            self._streak_start = None
            return False
        self.first_success = self.steps if self.first_success is None else self.first_success
        self._streak_start = self.steps if self._streak_start is None else self._streak_start
        return self.hold_steps is not None and self.steps - self._streak_start >= self.hold_steps


def recorded_features(env: Env) -> dict[str, FeatureSpec]:
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
    env: Env,
    seed: int,
    actor: Actor,
    *,
    max_steps: int | None = None,
    hold_success_s: float | None = HOLD_SUCCESS_S,
    record: bool = True,
    reset: bool = True,
) -> Episode:
    """Run ``actor`` from ``env.reset(seed)`` (or from the current state, ``reset=False``) until the
    episode ends (module docstring) and return it, recorded frame by frame when ``record``."""
    if reset:
        env.reset(seed)
    horizon = max_steps or env.horizon
    hold = SuccessHold(hold_success_s, env.fps)
    # A Gymnasium environment's episode also ends where it says so (demo.sim.foreign); the tasks' end by the rule above.
    ends_episodes = getattr(env, "ends_episodes", False)
    # Each step's frame (a fresh dict from env.frame) and command, stacked key by key at the end.
    steps: list[tuple[dict[str, np.ndarray], StepCommand]] = []
    frame = env.frame()
    for t in range(horizon):
        command = actor(env, frame, t)
        if record:
            steps.append((frame, command))
        obs, _, success, ended, _ = env.step(command.executed)
        frame = env.frame(obs)
        if hold.update(success) or (ended and ends_episodes):
            break
    return Episode(
        data=_stack(steps) if record else {}, success=bool(env.success()), length=hold.steps,
        first_success_step=hold.first_success, failure=env.task.failure(env),
    )


def _stack(steps: list[tuple[dict[str, np.ndarray], StepCommand]]) -> dict[str, np.ndarray]:
    """Per-frame arrays [T, ...]: the frames' keys, then the commands' (module docstring).

    ``np.array`` of a list of same-shape arrays is ``np.stack``'s result (same promotion, same
    values) at a fraction of its per-element cost."""
    if not steps:
        return {}
    unknown_target = np.zeros(7, dtype=np.float32)
    data = {key: np.array([frame[key] for frame, _ in steps]) for key in steps[0][0]}
    data["action"] = np.array([c.label for _, c in steps])
    data["info.executed_action"] = np.array([c.executed for _, c in steps])
    data["info.ee_target"] = np.array([unknown_target if c.ee_target is None else c.ee_target for _, c in steps])
    return data


def run_expert(
    env: Env,
    seed: int,
    rng: np.random.Generator | None = None,
    *,
    max_steps: int | None = None,
    hold_success_s: float | None = HOLD_SUCCESS_S,
    perturb: Callable[[Env, int], None] | None = None,
    record: bool = False,
    **style: Any,
) -> Episode:
    """The task's expert ``env.expert(rng, **style)`` from ``env.reset(seed)``, through :func:`rollout`.

    ``perturb(env, t)`` runs before step ``t``'s action (tests: take the cube out of the hand).
    """
    env.reset(seed)
    expert = env.expert(rng, **style)

    def act(env: Env, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        if perturb is not None:
            perturb(env, t)
        # float32 copies, as collection records them (the expert reuses its arrays from step to step).
        action = np.asarray(expert.act(env), dtype=np.float32)
        return StepCommand(executed=action, label=action, ee_target=np.asarray(expert.ee_target, np.float32))

    return rollout(env, seed, act, max_steps=max_steps, hold_success_s=hold_success_s, record=record, reset=False)


def env_store_meta(env: Env, task: str, options: dict[str, Any], provenance: list[dict[str, Any]]) -> StoreMeta:
    """The metadata of a store that records ``env``'s episodes of ``task``: fps, the recorded features,
    the action, the robot (by content: a non-built-in robot's files travel with the store), the task."""
    return StoreMeta(
        fps=float(env.fps),
        features=recorded_features(env),
        action=env.action_spec,
        robot=robot_record(env.robot) if env.robot is not None else None,
        task={"name": task, "options": dict(options), "horizon": int(env.horizon),
              **({"env": env.record()} if isinstance(env, (ForeignEnv, ForeignEnvSet)) else {})},
        provenance=list(provenance),
    )
