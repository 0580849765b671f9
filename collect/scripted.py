"""`demo collect --source scripted`: demonstrations from the tasks' state-feedback experts.

Episodes run in worker processes or Ray actors (:mod:`demo.executor`) and come back to this
process, the store's single writer, in episode order, so the store's bytes depend on the seed and
not on the executor or the number of workers. Finished
episodes are committed as soon as they (and every episode before them) are back, several per
commit when they arrive faster than one store write: Ctrl-C or a crash keeps every committed
episode, and no episode is ever half-written.

Seeds: episode ``i`` of a run with ``--seed S`` starts from ``env.reset(start_seed(S, i))``, a
32-bit seed derived with numpy's SeedSequence so that runs with different ``S`` do not share
initial states: ``episode_seed(S, i)`` (:mod:`demo.seeds`), except on a bimodal task (``avoid``), where episodes ``2k``
and ``2k + 1`` both start from ``episode_seed(S, k)`` and pass the obstacle on opposite sides (which
side goes first is drawn per pair; the pair shares its noise streams too, so it differs only in the
side). Each start state is then demonstrated both ways and the data are a genuinely bimodal
conditional. With one demonstration per start state the side is a function of the start state
that networks learn: diffusion and MSE-BC policies trained on such data re-took the demonstrated
side from 92% of its start states, and a diffusion policy sampled both sides from 1 start in 20.
With ``every_goal`` (``demo collect --every-goal``, a task whose words choose among goals: pick's coloured
cubes), the ``K`` episodes ``Kk .. Kk + K - 1`` start from ``episode_seed(S, k)`` and ask for each of the
``K`` goals in turn (the first for the one the seed draws): the same images, told apart by the words alone.
The store's ``seed`` column is the reset seed: the episodes of a pair or group share it.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from demo.collect.foreign import foreign_episode
from demo.collect.operators import Operator, get_profile
from demo.errors import DemoError
from demo.executor import ExecutorConfig, ordered_map
from demo.progress import Progress, Tick, or_silent
from demo.seeds import episode_seed
from demo.sim import load_robot, make_env
from demo.sim.foreign import is_foreign
from demo.sim.foreign_set import ForeignEnvSet
from demo.sim.randomize import Randomization
from demo.sim.rollout import Episode, StepCommand, env_store_meta, rollout
from demo.sim.tasks import TASKS
from demo.store import EpisodeStore, StoreMeta
from demo.store.location import store_path
from demo.store.output import open_output


@dataclass
class CollectConfig:
    """Everything that determines a scripted collection run (and so its bytes)."""

    task: str = "pick"
    episodes: int = 50
    seed: int = 0
    operator: str = "expert"
    noise: float = 0.0  # DART: std (rad) of noise on executed arm joint targets; the label stays clean
    robot: str | None = None  # robot config TOML; None = built-in
    task_options: dict[str, Any] = field(default_factory=dict)
    cameras: tuple[tuple[str, int, int], ...] = ()
    first_episode: int = 0  # index of the first episode in the seed sequence (to extend a run)
    # A Gymnasium environment's expert (task env:<name>, demo.collect.foreign): module:callable or a named one
    expert: str | None = None
    # Domain randomisation (demo.sim.randomize): kind -> level, drawn per episode from its seed
    randomize: dict[str, int] = field(default_factory=dict)
    # What every episode is told to do (the episode table's instruction column); None: the environment's own,
    # if it has one (a task set's member: Meta-World's task as a sentence)
    instruction: str | None = None
    # Every start state demonstrated once per goal its words can name (pick with colours=K: K consecutive
    # episodes from one reset seed, each asking for another cube), so identical scenes differ only in the words
    every_goal: bool = False


def make_env_for(config: CollectConfig) -> Any:
    if is_foreign(config.task):  # it brings its own robot and cameras
        if config.randomize:
            raise DemoError("--randomize", "changes demo's own scenes; a Gymnasium environment's are its own")
        return make_env(config.task, **config.task_options)
    env = make_env(config.task, robot=load_robot(config.robot), cameras=config.cameras, **config.task_options)
    if config.randomize:
        env.set_randomization(Randomization(config.randomize))
    return env


BIMODAL_TASKS = ("avoid",)  # tasks whose expert demonstrates one of two modes, demonstrated in pairs


def episodes_per_start(config: CollectConfig) -> int:
    """How many consecutive episodes share a start state: a bimodal task's pair, ``every_goal``'s goals, else 1."""
    if config.every_goal:  # checked first: a bimodal task's words name no goal either
        goals = TASKS[config.task](**config.task_options).goals if config.task in TASKS else 0
        if goals < 2:
            raise DemoError("--every-goal", f"task {config.task} with options {config.task_options or '{}'} names no "
                                            "choice of goal in words (pick with --task-opt colours=2 or 3 does)")
        return goals
    return 2 if config.task in BIMODAL_TASKS else 1


def start_seed(config: CollectConfig, index: int) -> int:
    """The ``env.reset`` seed of episode ``index``: the episodes of a group (:func:`episodes_per_start`) share it."""
    return episode_seed(config.seed, index // episodes_per_start(config))


def balanced_modes(config: CollectConfig, index: int) -> dict[str, Any]:
    """Expert style of a bimodal task: the two episodes of a pair (one start state) take opposite
    sides, in an order drawn per pair."""
    if config.task not in BIMODAL_TASKS:
        return {}
    pair_flip = np.random.default_rng([config.seed, index // 2, 3]).random() < 0.5
    return {"p_left": float(pair_flip ^ (index % 2 == 1))}


def hold_action(env: Any) -> np.ndarray:
    """The command that keeps the robot where it is: measured joint angles and gripper closedness."""
    obs = env.observe()
    return np.r_[obs["obs.joint_pos"], obs["obs.gripper"]].astype(np.float32)


def scripted_episode(env: Any, config: CollectConfig, index: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Run one scripted episode: expert, optionally through an operator profile and DART noise."""
    seed = start_seed(config, index)
    if is_foreign(config.task):  # a task set (demo.sim.foreign_set) runs episode `index` in one of its members
        member = env.select(index) if isinstance(env, ForeignEnvSet) else env
        return foreign_episode(member, config.expert or "", seed, config.noise, config.instruction)
    rng = np.random.default_rng([seed, 1])
    profile = get_profile(config.operator)
    n_arm = len(env.robot.arm_joints)
    operator = Operator(profile, rng, env.fps, env.horizon, n_arm) if profile.name != "expert" else None
    env.reset(seed)
    if config.every_goal:  # the group's first episode asks for the goal the seed drew, the next ones for the others
        env.task.shift_goal(index % episodes_per_start(config))
    style = {**(operator.expert_style if operator else {}), **balanced_modes(config, index)}
    expert = env.expert(rng=np.random.default_rng([seed, 2]), **style)
    last_sent: list[np.ndarray] = [hold_action(env)]

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        if operator:
            operator.steer(expert)
        clean = np.asarray(expert.act(env), dtype=np.float32)
        sent = operator.command(t, clean, last_sent[0]) if operator else clean
        executed = sent
        if config.noise > 0:  # a noisy copy; without noise the one array is sent and recorded (neither is written to)
            executed = sent.copy()
            executed[:n_arm] += rng.normal(0.0, config.noise, n_arm).astype(np.float32)
        last_sent[0] = sent
        # A person's dataset holds what they sent; a DART dataset holds the clean expert label.
        label = sent if operator else clean
        return StepCommand(executed=executed, label=label, ee_target=np.asarray(expert.ee_target, np.float32))

    episode: Episode = rollout(env, seed, act, reset=False)
    info: dict[str, Any] = {
        "success": episode.success,
        "seed": seed,
        "source": "scripted",
        "operator": config.operator,
        "task": config.task,
        "noise": float(config.noise),
        "expert_mode": str(expert.mode) if expert.mode is not None else "",
        "first_success_step": -1 if episode.first_success_step is None else episode.first_success_step,
    }
    if operator:
        info["operator_failure"] = operator.failure_kind
    if config.randomize:  # this episode's draws (its seed gives them again: demo.sim.randomize)
        info["randomization"] = json.dumps(env.randomized, sort_keys=True)
    told = config.instruction or env.instruction
    if told:
        info["instruction"] = told
    return episode.data, info


# -------------------------------------------------------------------------- workers
_worker_env: Any = None
_worker_config: CollectConfig | None = None


def _worker_init(config: CollectConfig) -> None:
    global _worker_env, _worker_config
    _worker_config = config
    _worker_env = make_env_for(config)


def _worker_run(index: int) -> tuple[int, dict[str, np.ndarray], dict[str, Any]]:
    assert _worker_config is not None
    data, info = scripted_episode(_worker_env, _worker_config, index)
    return index, data, info


EpisodeResult = tuple[int, dict[str, np.ndarray], dict[str, Any]]
MAX_BATCH_FRAMES = 50_000


def run_episodes(config: CollectConfig, executor: ExecutorConfig) -> Iterator[list[EpisodeResult]]:
    """Yield batches of ``(index, data, info)`` in episode order.

    ``process`` with 0 workers simulates in this process, one episode per batch. Otherwise the
    workers simulate while this process only writes: each batch holds every episode that has
    finished (in order) since the last one, up to :data:`MAX_BATCH_FRAMES` frames, so the per-write
    overhead of the store is shared by all of them and never holds up the simulation.
    """
    indices = range(config.first_episode, config.first_episode + config.episodes)
    if executor.kind == "process" and executor.workers <= 0:
        env = make_env_for(config)
        try:
            for i in indices:
                data, info = scripted_episode(env, config, i)
                yield [(i, data, info)]
        finally:
            env.close()
        return
    for ready in ordered_map(_worker_init, (config,), _worker_run, indices, executor, label=lambda i: f"episode {i}"):
        batch: list[EpisodeResult] = []
        frames = 0
        for result in ready:
            batch.append(result)
            frames += len(result[1]["action"])
            if frames >= MAX_BATCH_FRAMES:
                yield batch
                batch, frames = [], 0
        if batch:
            yield batch


def store_meta(config: CollectConfig, env: Any) -> StoreMeta:
    return env_store_meta(env, config.task, config.task_options,
                          [{"op": "collect", "source": "scripted", **_jsonable(asdict(config))}])


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    # "expert" only where there is one (a Gymnasium environment's): the tasks' provenance reads as before
    return {k: (list(map(list, v)) if k == "cameras" else v) for k, v in d.items()
            if k != "episodes" and not (k == "expert" and v is None)}


@dataclass
class CollectResult:
    path: str
    episodes: int
    successes: int
    frames: int
    seconds: float
    modes: dict[str, int]
    # What the experts were asked to be: a deliberately imperfect operator or noise explains a low success rate.
    operator: str = "expert"
    noise: float = 0.0
    task: str = ""

    @property
    def success_rate(self) -> float:
        return self.successes / max(1, self.episodes)


# Below this share of successful episodes a scripted run is suspect: the experts succeed on 50/50
# episodes of every task on the built-in arm, so a lower rate points at the robot, the task options,
# the operator profile or the noise rather than at chance.
SUCCESS_WARNING = 0.9


def check_success(result: CollectResult, min_success: float | None = None) -> str | None:
    """Judge a finished run's measured success rate (``result.success_rate``, a fraction).

    Raises a :class:`DemoError` naming the store when it is below ``min_success`` (a fraction in
    [0, 1]; None: no threshold), or when the expert itself (no imperfect operator, no noise) succeeded on
    no episode; the episodes already collected stay stored. Otherwise returns a
    one-line warning when it is below :data:`SUCCESS_WARNING`, else None.
    """
    if min_success is not None and not 0.0 <= min_success <= 1.0:
        raise DemoError("--min-success", f"must be a fraction in [0, 1], got {min_success}")
    rate = result.success_rate
    # (A Gymnasium environment's expert is judged by the environment, which may report no success at all.)
    if result.successes == 0 and result.operator == "expert" and result.noise == 0 and not is_foreign(result.task):
        # The expert itself never succeeds: no demonstration of the task (a robot it cannot work, task options)
        raise DemoError(result.path, f"the expert succeeded on none of {result.episodes} episodes: check the robot "
                                     "config (demo robot check) and the task options (the episodes stay stored)")
    if min_success is not None and rate < min_success:
        raise DemoError(result.path, f"expert success {rate:.2f} < --min-success {min_success:g} "
                                     f"({result.episodes} episodes stay stored)")
    if rate < SUCCESS_WARNING:
        head = f"{result.path}: expert success {rate:.2f} ({result.successes}/{result.episodes} episodes) is below {SUCCESS_WARNING:g}"
        if result.operator != "expert" or result.noise > 0:  # asked for: not the robot's fault
            chosen = " and ".join(([f"--operator {result.operator}"] if result.operator != "expert" else [])
                                  + ([f"--noise {result.noise:g}"] if result.noise > 0 else []))
            return f"{head}, as {chosen} may cause (the expert alone: --operator expert, no --noise)"
        return f"{head}: check the robot config and the task options"
    return None


def collect_tick(task: str, done: int, total: int, successes: int, frames: int, seconds: float) -> Tick:
    """Progress after ``done`` of ``total`` episodes are committed: successes, frames recorded so far
    and the recording rate (frames per second of wall time)."""
    return Tick(f"collect {task}", done, total,
                {"success": f"{successes}/{done}", "frames": frames, "frames/s": frames / max(seconds, 1e-9)})


def collect_scripted(
    config: CollectConfig,
    out: str | Path,
    *,
    workers: int = 1,
    executor: ExecutorConfig | None = None,
    append: bool = False,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> CollectResult:
    """Collect ``config.episodes`` scripted episodes into the store at ``out``.

    Episodes run on ``executor`` (default: ``workers`` local processes; 0 = this process); the store
    holds the same bytes whichever runs them. ``progress`` gets a :func:`collect_tick` once the
    store is open and after each committed episode.
    """
    if config.episodes < 1:
        raise DemoError("--episodes", "must be at least 1")
    if config.noise < 0:
        raise DemoError("--noise", "must be >= 0")
    if is_foreign(config.task) != (config.expert is not None):
        raise DemoError("--expert", "names the expert of a Gymnasium environment (--env); the tasks bring their own"
                        if config.expert is not None else "a Gymnasium environment (--env) needs --expert")
    if is_foreign(config.task) and (config.operator != "expert" or config.robot or config.cameras):
        raise DemoError("--env", "a Gymnasium environment records its own expert, robot and cameras: --operator, "
                                 "--robot and --camera do not apply")
    episodes_per_start(config)  # --every-goal on a task without goals in words fails here
    executor = executor or ExecutorConfig("process", workers)
    executor.check()
    get_profile(config.operator)
    out = store_path(out)  # a local path or a URL (an unknown scheme or a missing backend fails here)
    env = make_env_for(config)
    try:
        meta = store_meta(config, env)
        if isinstance(env, ForeignEnvSet):  # --episodes is per task of a set
            config = replace(config, episodes=config.episodes * len(env.tasks))
    finally:
        env.close()
    report = or_silent(progress)
    done = successes = frames = 0
    modes: dict[str, int] = {}
    start = time.perf_counter()
    with open_output(out, meta, append, overwrite) as store:  # an exception abandons it: see open_output
        if append:
            config.first_episode = max(config.first_episode, _next_episode_index(store, config))
        report(collect_tick(config.task, 0, config.episodes, 0, 0, 0.0))
        for batch in run_episodes(config, executor):
            store.append_episodes([(data, info) for _, data, info in batch])
            for _, data, info in batch:
                done += 1
                successes += int(info["success"])
                frames += len(data["action"])
                if info.get("expert_mode"):
                    modes[info["expert_mode"]] = modes.get(info["expert_mode"], 0) + 1
                report(collect_tick(config.task, done, config.episodes, successes, frames, time.perf_counter() - start))
    return CollectResult(str(out), config.episodes, successes, frames, time.perf_counter() - start, modes,
                         config.operator, config.noise, config.task)


def _next_episode_index(store: EpisodeStore, config: CollectConfig) -> int:
    """When appending with the same seed, continue the seed sequence instead of repeating episodes.

    Seeds are counted, not just looked up: after an odd number of paired episodes the next episode
    is the second of the last pair (same start state), not the first of a new one."""
    stored = Counter(store.column("seed").tolist()) if store.num_episodes else Counter()
    i = 0
    while stored[start_seed(config, i)] > 0:
        stored[start_seed(config, i)] -= 1
        i += 1
    return i
