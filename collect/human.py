"""What kinesthetic and VR-style collection share: the store layout, episode seeds, the run loop.

Store: a human episode records everything a scripted one does (``recorded_features(env)``, the
same ``store_meta``) plus two per-frame keys, ``info.ik_ok`` and ``info.ik_error``
(:func:`demo.collect.retarget.retarget_features`): whether the person's command could be executed
as given (VR: the hand pose was reached by IK; kinesthetic: the recorded joints were inside the
joint range). The episode table gets ``source`` ("kinesthetic"/"vr"), ``operator`` (the person),
``unreachable_frames`` (frames with ``ik_ok`` false), ``first_success_step``, and ``input`` /
``input_line`` (file and line where the episode starts).

Initial states: an input file names each episode's initial state by a header (``episode_seed``);
an episode without one starts from ``env.reset(episode_seed(seed, i))``, the seed scripted
collection uses for its ``i``-th episode, so a file made from ``demo collect --source scripted
--seed S`` replays from the same states with ``seed=S``.

Length: an episode lasts the recording plus at most ``TAIL_S`` holding the last command; like a
scripted one it ends early once the task's success has held for 0.5 s.

Input files are parsed completely before the store is opened, so a bad line changes nothing.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from demo.collect.retarget import retarget_features
from demo.collect.scripted import (CollectConfig, CollectResult, collect_tick, make_env_for,
                                   store_meta)
from demo.store.output import open_output
from demo.errors import DemoError
from demo.progress import Progress, or_silent
from demo.seeds import episode_seed
from demo.sim.rollout import Episode, StepCommand, rollout
from demo.store import StoreMeta
from demo.store.location import store_path

HUMAN_SOURCES = ("kinesthetic", "vr")
DEFAULT_OPERATOR = "human"
TAIL_S = 1.0  # s of holding the last command after a recording ends


@dataclass
class HumanConfig:
    """Everything that determines a human-input collection run."""

    task: str
    source: str  # "kinesthetic" | "vr" | "leader"
    input: str  # the input file
    seed: int = 0
    operator: str | None = None  # None: the file's header, else DEFAULT_OPERATOR
    robot: str | None = None
    task_options: dict[str, Any] = field(default_factory=dict)
    cameras: tuple[tuple[str, int, int], ...] = ()
    settings: dict[str, Any] = field(default_factory=dict)  # source-specific (ik, scale, calib, ...)
    instruction: str = ""  # what every episode was told to do (the episode table's instruction column)

    def collect_config(self) -> CollectConfig:
        return CollectConfig(
            task=self.task, episodes=1, seed=self.seed, operator="expert", robot=self.robot,
            task_options=dict(self.task_options), cameras=tuple(self.cameras),
        )


@dataclass
class HumanCollectResult(CollectResult):
    unreachable_frames: int = 0
    tracking_error_rad: dict[str, dict[str, float]] | None = None  # leader-follower: per arm joint, mean and max


@dataclass
class InputEpisode:
    """One episode read from an input file: where it starts and its own header fields."""

    line: int  # 1-based line of the file where the episode starts
    seed: int | None  # env.reset seed from the header, if any
    operator: str | None


class HumanCommand(NamedTuple):
    """One control step of a person's recording, as the robot will execute it."""

    q: np.ndarray  # arm joint targets (rad)
    grip: float  # gripper closedness, 0 open .. 1 closed
    ee_target: np.ndarray  # (7,) EE pose behind the command: position (m, base frame) + quaternion wxyz
    ok: bool  # executable as the person gave it (reached by IK / inside the joint range)
    error: tuple[float, float]  # what was not: (m, rad) for VR poses, (0, rad beyond the range) for joints


def play_recording(
    env: Any, seed: int, length: int, command_at: Callable[[int], HumanCommand]
) -> tuple[Episode, np.ndarray, np.ndarray]:
    """Execute a recording of ``length`` control steps from the current state (already reset).

    Step ``t`` executes ``command_at(t)``; past the end the callee holds its last command, for
    at most ``TAIL_S``. Returns the episode, ``info.ik_ok`` [T, 1] and ``info.ik_error`` [T, 2].
    """
    ok: list[bool] = []
    err: list[tuple[float, float]] = []

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        c = command_at(t)
        ok.append(c.ok)
        err.append(c.error)
        command = np.empty(len(c.q) + 1, dtype=np.float32)
        command[:-1] = c.q
        command[-1] = c.grip
        return StepCommand(executed=command, label=command, ee_target=np.asarray(c.ee_target, dtype=np.float32))

    episode = rollout(env, seed, act, reset=False, max_steps=length + int(round(TAIL_S * env.fps)))
    return episode, np.array(ok, dtype=bool)[:, None], np.array(err, dtype=np.float32)


def reset_seed(episode: InputEpisode, seed: int, index: int) -> int:
    return int(episode.seed) if episode.seed is not None else episode_seed(seed, index)


def human_store_meta(config: HumanConfig, env: Any) -> StoreMeta:
    """The scripted store layout (``store_meta``) plus the per-frame human keys and provenance."""
    meta = store_meta(config.collect_config(), env)
    meta.features = {**meta.features, **retarget_features()}
    meta.provenance = [{
        "op": "collect", "source": config.source, "input": str(config.input), "seed": config.seed,
        "operator": config.operator, "task": config.task, "robot": config.robot,
        "task_options": dict(config.task_options), "cameras": [list(c) for c in config.cameras],
        **config.settings,
    }]
    return meta


EpisodeRunner = Callable[[Any, int, int], tuple[dict[str, np.ndarray], dict[str, Any]]]


def record_episodes(
    config: HumanConfig,
    count: int,
    run_episode: EpisodeRunner,
    out: str | Path,
    *,
    append: bool = False,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> HumanCollectResult:
    """Run ``run_episode(env, index, count)`` for every input episode and append each to ``out``.

    ``run_episode`` returns ``(data, info)`` as ``store.append_episode`` takes them. ``progress``
    gets a ``collect_tick`` once the store is open and after each committed episode.
    """
    out = store_path(out)
    report = or_silent(progress)
    env = make_env_for(config.collect_config())
    start = time.perf_counter()
    successes = frames = unreachable = 0
    try:
        store = open_output(out, human_store_meta(config, env), append, overwrite)
        try:
            report(collect_tick(config.task, 0, count, 0, 0, 0.0))
            for index in range(count):
                data, info = run_episode(env, index, count)
                store.append_episode(data, **info)
                successes += int(info["success"])
                frames += len(data["action"])
                unreachable += int(info.get("unreachable_frames", 0))
                report(collect_tick(config.task, index + 1, count, successes, frames, time.perf_counter() - start))
        except BaseException:
            store.abandon()  # failed before its first episode: no store is left (see open_output)
            raise
        finally:
            store.close()
    finally:
        env.close()
    return HumanCollectResult(path=str(out), episodes=count, successes=successes, frames=frames,
                              seconds=time.perf_counter() - start, modes={}, unreachable_frames=unreachable)


def episode_info(
    config: HumanConfig, episode: InputEpisode, seed: int, success: bool, first_success: int | None, ik_ok: np.ndarray
) -> dict[str, Any]:
    return {
        "success": bool(success),
        "seed": int(seed),
        "source": config.source,
        "operator": config.operator or episode.operator or DEFAULT_OPERATOR,
        "task": config.task,
        "unreachable_frames": int((~ik_ok.astype(bool)).sum()),
        "first_success_step": -1 if first_success is None else int(first_success),
        "input": Path(config.input).name,
        "input_line": int(episode.line),
        **({"instruction": config.instruction} if config.instruction else {}),
    }


def check_task(path: Path, line: int, header_task: Any, task: str) -> None:
    if header_task is not None and header_task != task:
        raise DemoError(f"{path}:{line}", f"episode was recorded for task {header_task!r}, not {task!r}")


def as_floats(where: str, name: str, value: Any, n: int) -> np.ndarray:
    """A list of ``n`` finite numbers, or a DemoError naming ``where`` (file:line)."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise DemoError(where, f"'{name}' must be a list of {n} numbers, got {_short(value)}")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise DemoError(where, f"'{name}' must hold numbers, got {_short(value)}")
    arr = np.asarray(value, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise DemoError(where, f"'{name}' has a non-finite value (NaN or inf): {_short(value)}")
    return arr


def as_float(where: str, name: str, value: Any) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise DemoError(where, f"'{name}' must be a number, got {_short(value)}")
    v = float(value)
    if not np.isfinite(v):
        raise DemoError(where, f"'{name}' is not finite ({value})")
    return v


MAX_RECORDING_S = 3600.0  # one demonstration lasts minutes; an hour-long span is a broken time column


def check_time(where: str, t: float, previous: float | None, start: float | None = None) -> None:
    """``t`` (s) must follow ``previous`` and lie within MAX_RECORDING_S of the episode's ``start``
    (what is played back is resampled over that span: it is a size to bound before allocating)."""
    if previous is not None and t <= previous:
        what = "repeats" if t == previous else "goes backwards"
        raise DemoError(where, f"time {what}: t={t:g} s after t={previous:g} s")
    if start is not None and t - start > MAX_RECORDING_S:
        raise DemoError(where, f"t={t:g} s is {t - start:g} s after the episode's first sample; an episode lasts "
                               f"at most {MAX_RECORDING_S:g} s")


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
