"""Dense task rewards for reinforcement learning, as linear functions of documented task features.

The simulator's reward is sparse (1.0 on success steps, :mod:`demo.gym.env`) and stays what
``demo eval`` judges; RL in a CPU budget needs a signal at every step. Each task here has a
:class:`TaskReward`: features ``phi(s')`` of the state *after* a step, computed from the
observations alone (plus whether the task has failed for good, which no observation shows), and
the weights ``w`` of the dense reward ``r = w . phi`` (per control step). Because the dense
reward is linear in the features, linear inverse RL (:mod:`demo.rl.irl_linear`) recovers
weights that compare directly with these, and any learned reward can be correlated with it.

``reach`` (units of each feature in brackets; weights per control step):

- ``pos_err`` [m]: distance from the EE site to the target position, weight -10 (-0.1 per cm);
- ``rot_err`` [rad]: angle of the rotation from the EE orientation to the target's, weight -1;
- ``success`` [0/1]: both within the task's tolerances (``pos_tol`` 1 cm, ``rot_tol`` 0.1 rad by
  default), weight +2, which outweighs the distance terms left at the tolerances (-0.2).

``avoid``:

- ``goal_err`` [m]: distance from the EE site to the goal, weight -10;
- ``touched`` [0/1]: the robot has touched the obstacle this episode (latched), weight -5 per step,
  so a collision costs every step that follows it (RL episodes do not end on it);
- ``success`` [0/1]: within ``tol`` (2 cm) of the goal and never touched, weight +2.

``pick`` (robosuite's staged lift reward made linear):

- ``reach_err`` [m]: distance from the EE site to the cube centre, weight -10;
- ``lift`` [m]: the cube's height above its resting height (``cube_size / 2``), clipped to
  [0, ``lift_height``] (10 cm by default), weight +20 (+2 at the full lift);
- ``success`` [0/1]: the cube at least ``lift_height`` above its rest (the task's success), weight +2.

``stack`` (every cycle of ``repeat`` K, one cube or several): a finished stack that is not the last moves
the pad on and puts the cubes back in the same control step, so the state after it looks like a new
start and no function of that state alone can pay for it, nor can a distance of that state: the
distances jump back up when a cycle ends, and a reward of the state would punish finishing one. Its
reward reads the transition:

- ``success`` [0/1]: every cube at its level on the pad (2 cm across, 1 cm in height) with the gripper
  open: the last stack, held (the task's success), weight +1 per step;
- the **event** ``progress`` (:attr:`TaskReward.event`): on the step a cycle ends (the pad's centre moved
  by more than 1 cm between the states before and after it) +:data:`CYCLE_BONUS`; on every other step
  the change of the potential ``Phi(s') - Phi(s)`` (Ng et al. 1999's shaping, undiscounted), where
  ``Phi = -(STAGE_WEIGHT * cubes not yet stacked + REACH_WEIGHT * |EE - cube| + PLACE_WEIGHT * |cube - its
  place|)`` [m] for the next cube to stack (the first, in order, not at its level): the arm is paid as it
  brings the gripper to the cube and the cube to its place, and paid back nothing it has not earned. The
  sparse form of then (the cycle alone, +1) moved a residual over BC from 38 to 47/100 in 1.2 million steps.

The features are numpy over batches: every function takes observation arrays with a leading batch
axis (a store's episodes or the observations of several environments). :func:`pearson` measures how
well a learned reward follows the dense one over the same transitions.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.errors import DemoError

Features = Callable[[Mapping[str, np.ndarray], np.ndarray, Mapping[str, Any]], np.ndarray]


def quat_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) of the rotations between unit quaternions ``a`` and ``b`` ``[N, 4]`` (wxyz, any sign)."""
    dot = np.abs(np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64), axis=-1))
    return 2.0 * np.arccos(np.minimum(dot, 1.0))


def _reach(obs: Mapping[str, np.ndarray], failed: np.ndarray, options: Mapping[str, Any]) -> np.ndarray:
    pos_err = np.linalg.norm(np.asarray(obs["obs.ee_pos"], np.float64) - obs["obs.goal_pos"], axis=-1)
    rot_err = quat_angles(obs["obs.ee_quat"], obs["obs.goal_quat"])
    success = (pos_err < float(options.get("pos_tol", 0.01))) & (rot_err < float(options.get("rot_tol", 0.1)))
    return np.stack([pos_err, rot_err, success.astype(np.float64)], axis=-1)


def _avoid(obs: Mapping[str, np.ndarray], failed: np.ndarray, options: Mapping[str, Any]) -> np.ndarray:
    goal_err = np.linalg.norm(np.asarray(obs["obs.ee_pos"], np.float64) - obs["obs.goal_pos"], axis=-1)
    touched = np.asarray(failed, dtype=np.float64)
    success = (goal_err < float(options.get("tol", 0.02))) & (touched == 0)
    return np.stack([goal_err, touched, success.astype(np.float64)], axis=-1)


def _pick(obs: Mapping[str, np.ndarray], failed: np.ndarray, options: Mapping[str, Any]) -> np.ndarray:
    cube = np.asarray(obs["obs.object_pos"], np.float64)[:, 0]  # [N, 3]: the one cube
    reach_err = np.linalg.norm(np.asarray(obs["obs.ee_pos"], np.float64) - cube, axis=-1)
    lift_height = float(options.get("lift_height", 0.10))
    height = cube[:, 2] - float(options.get("cube_size", 0.04)) / 2
    success = height >= lift_height
    return np.stack([reach_err, np.clip(height, 0.0, lift_height), success.astype(np.float64)], axis=-1)


def _stack_places(obs: Mapping[str, np.ndarray], options: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stack's cubes ``[.., N, 3]``, each one's place on the pad's stack (its centre, same shape), and whether it is
    at its place ``[.., N]`` (2 cm across, 1 cm in height)."""
    cubes = np.asarray(obs["obs.object_pos"], np.float64)
    places = np.broadcast_to(np.asarray(obs["obs.goal_pos"], np.float64)[..., None, :], cubes.shape).copy()
    places[..., 2] = (np.arange(cubes.shape[-2]) + 0.5) * float(options.get("cube_size", 0.04))
    at_level = (np.linalg.norm(cubes[..., :2] - places[..., :2], axis=-1) <= 0.02) & (np.abs(cubes[..., 2] - places[..., 2]) <= 0.01)
    return cubes, places, at_level


def _stack(obs: Mapping[str, np.ndarray], failed: np.ndarray, options: Mapping[str, Any]) -> np.ndarray:
    at_level = _stack_places(obs, options)[2]
    open_hand = np.asarray(obs["obs.gripper"], np.float64)[:, 0] < 0.5
    return (at_level.all(axis=1) & open_hand).astype(np.float64)[:, None]


CYCLE_BONUS = 5.0  # stack: reward for a finished cycle
STAGE_WEIGHT = 5.0  # stack: potential per cube still to stack
REACH_WEIGHT = 10.0  # stack: potential per m between the EE site and the next cube
PLACE_WEIGHT = 10.0  # stack: potential per m between the next cube and its place on the pad


def pad_moved(before: Mapping[str, np.ndarray], after: Mapping[str, np.ndarray]) -> np.ndarray:
    """1 where the pad's centre moved by more than 1 cm across a step (a finished stack cycle), else 0."""
    step = np.asarray(after["obs.goal_pos"], np.float64) - np.asarray(before["obs.goal_pos"], np.float64)
    return (np.linalg.norm(step, axis=-1) > 0.01).astype(np.float64)


def stack_potential(obs: Mapping[str, np.ndarray], options: Mapping[str, Any]) -> np.ndarray:
    """``Phi`` of the module docstring over a batch ``[..]`` of stack states."""
    cubes, places, at_level = _stack_places(obs, options)
    place_err = np.linalg.norm(cubes - places, axis=-1)  # [.., N]
    stacked = np.cumprod(at_level, axis=-1).sum(axis=-1)  # the cubes stacked in order
    nxt = np.minimum(stacked, cubes.shape[-2] - 1)[..., None, None]
    cube = np.take_along_axis(cubes, nxt, axis=-2)[..., 0, :]
    reach = np.linalg.norm(np.asarray(obs["obs.ee_pos"], np.float64) - cube, axis=-1)
    err = np.take_along_axis(place_err, nxt[..., 0], axis=-1)[..., 0]
    todo = cubes.shape[-2] - stacked
    return -(STAGE_WEIGHT * todo + np.where(todo > 0, REACH_WEIGHT * reach + PLACE_WEIGHT * err, 0.0))


def _progress(before: Mapping[str, np.ndarray], after: Mapping[str, np.ndarray], options: Mapping[str, Any]) -> np.ndarray:
    """Stack's transition reward: :data:`CYCLE_BONUS` where a cycle ended, else the potential's change."""
    cycle = pad_moved(before, after)
    shaping = stack_potential(after, options) - stack_potential(before, options)
    return np.where(cycle > 0, CYCLE_BONUS, shaping)


Event = Callable[[Mapping[str, np.ndarray], Mapping[str, np.ndarray], Mapping[str, Any]], np.ndarray]


@dataclass(frozen=True)
class TaskReward:
    """A task's dense reward ``weights . features(obs, failed, options)`` (module docstring), plus an
    ``event`` of the transition where the state after a step cannot say what happened (stack's cycles)."""

    task: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    weights: tuple[float, ...]  # per control step, per unit of each feature
    compute: Features
    event: Event | None = None  # (obs before, obs after) [..] -> reward [..] per step, added to the features' term

    def features(self, obs: Mapping[str, np.ndarray], failed: np.ndarray | None = None,
                 options: Mapping[str, Any] | None = None) -> np.ndarray:
        """``[N, F]`` features of ``N`` states: ``obs`` arrays ``[N, ...]`` (the env's ``obs.*`` keys),
        ``failed [N]`` whether the task has failed for good (default: never), ``options`` the task's."""
        n = len(next(iter(obs.values())))
        failed = np.zeros(n, dtype=bool) if failed is None else np.asarray(failed, dtype=bool)
        return self.compute(obs, failed, options or {})

    def __call__(self, obs: Mapping[str, np.ndarray], failed: np.ndarray | None = None,
                 options: Mapping[str, Any] | None = None) -> np.ndarray:
        """``[N]`` dense rewards of ``N`` states (per control step)."""
        return self.features(obs, failed, options) @ np.asarray(self.weights)

    def events(self, before: Mapping[str, np.ndarray], after: Mapping[str, np.ndarray],
               options: Mapping[str, Any] | None = None) -> np.ndarray | float:
        """The event term over a batch of transitions (0 for a task without one); ``options`` the task's."""
        return 0.0 if self.event is None else self.event(before, after, options or {})

    def to_json(self) -> dict[str, Any]:
        return {"task": self.task, "features": list(self.names), "units": list(self.units),
                "weights": list(self.weights), **({"event": self.event.__name__.strip("_")} if self.event else {})}


TASK_REWARDS: dict[str, TaskReward] = {
    "reach": TaskReward("reach", ("pos_err", "rot_err", "success"), ("m", "rad", "1"), (-10.0, -1.0, 2.0), _reach),
    "avoid": TaskReward("avoid", ("goal_err", "touched", "success"), ("m", "1", "1"), (-10.0, -5.0, 2.0), _avoid),
    "pick": TaskReward("pick", ("reach_err", "lift", "success"), ("m", "m", "1"), (-10.0, 20.0, 2.0), _pick),
    "stack": TaskReward("stack", ("success",), ("1",), (1.0,), _stack, event=_progress),
}


def task_reward(task: str, where: str = "--reward") -> TaskReward:
    """The dense reward of ``task``; a DemoError for a task that has none yet."""
    if task not in TASK_REWARDS:
        raise DemoError(where, f"no dense task reward is defined for {task!r} (defined: {', '.join(TASK_REWARDS)}; "
                               "see demo.rl.rewards)")
    return TASK_REWARDS[task]


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two arrays of rewards over the same transitions (0 when either is constant)."""
    a, b = np.ravel(a).astype(np.float64), np.ravel(b).astype(np.float64)
    sa, sb = a.std(), b.std()
    return float(((a - a.mean()) * (b - b.mean())).mean() / (sa * sb)) if sa > 0 and sb > 0 else 0.0
