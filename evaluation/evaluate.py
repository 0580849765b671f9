"""Policy evaluation by rollouts in the simulator: success rate with a Wilson interval, lengths, failures.

Episode ``i`` of ``demo eval --seed S`` starts from ``env.reset(eval_seeds(S)[i])``
(:mod:`demo.seeds`: a seed stream disjoint from the one demonstrations are collected with);
the seeds used are checked against the seeds of the run's training data and the overlap reported.
Each episode runs :func:`demo.sim.rollout.rollout` (the loop collection uses, and its ending rule):
it ends at the task horizon, or once success has held for 0.5 s. Outcomes:

- ``success``: the success predicate holds at the end;
- ``timeout``: it never held before the horizon;
- ``lost``: it held at some point but not at the end (e.g. a lifted cube dropped);
- the task's own reason where it has failed for good (``Task.failure``: avoid's ``collision``);
- ``error``: the policy produced a non-finite action or the simulation failed.

Robots: a policy evaluates on a robot it was trained on (the run's first by default; ``--robot``
names another of a union's robots, or a robot config TOML). A robot it was not trained on is
refused unless the policy acts in end-effector space (``ee7``, ``ee_delta``, ``ee_abs``: poses in
the robot's base frame, which the arm's own IK turns into its joint targets) and reads observations
that robot reports in the same shapes; the result then says the robot is new to the policy.
Joint-space actions are one arm's joint targets and never transfer.

The flywheel (``demo eval --record STORE``): every rollout is appended to ``STORE`` as an episode
(created with the evaluation environment's features, task and robot if absent, else checked to
record the same), source ``policy``, with the columns ``run``, ``success``, ``outcome`` and ``instruction``
(what the episode was told, :attr:`EpisodeOutcome.instruction`); this
process alone writes, in episode order (a task set's member by member: its episodes run so, one member
built at a time), so the store's bytes do not depend on ``--workers`` or ``--executor``. ``demo curate``,
then ``demo train`` (which keeps the successful episodes) turn a deployed policy's own successes into
training data. An ``error`` episode is not recorded (its last action was not finite).

Evaluation is deterministic for a seed, whatever ``--workers`` and ``--executor`` (worker processes
or Ray actors, :mod:`demo.executor`): every episode's state depends only
on its seed, and torch runs single-threaded here (a small network at batch 1 gains nothing from
threads, and thread counts could change float summation order).
"""

from __future__ import annotations

import math
import time
from contextlib import ExitStack
from collections.abc import Iterator, Sequence
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from demo.errors import DemoError
from demo.executor import ExecutorConfig, ordered_map
from demo.progress import Progress, Tick, or_silent
from demo.seeds import EVAL_OFFSET, eval_seeds
from demo.sim import make_env
from demo.sim.robot_record import resolve_robot, robot_record
from demo.sim.foreign import is_foreign
from demo.sim.foreign_set import ForeignEnvSet
from demo.sim.randomize import Randomization
from demo.sim.tasks import TASKS
from demo.sim.rollout import StepCommand, env_store_meta, rollout
from demo.store.instructions import check_instruction
from demo.store.output import open_output
from demo.store.robot_files import same_body
from demo.policies.actions import make_action_adapter
from demo.policies.actor import ExecConfig, PolicyActor
from demo.policies.checkpoint import PolicyBundle, load_bundle, now, robot_home, trained_robots
from demo.policies.device import resolve_device
from demo.evaluation.video import write_video

Z95 = 1.959963984540054


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """95% Wilson score interval of a binomial proportion (sensible at 0% and 100%, unlike Wald)."""
    if n <= 0:
        return (0.0, 1.0)
    if successes == 0:
        return (0.0, min(1.0, z * z / (n + z * z)))
    if successes == n:
        return (max(0.0, n / (n + z * z)), 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


@dataclass
class EpisodeOutcome:
    index: int
    seed: int
    success: bool
    length: int  # control steps
    first_success_step: int | None
    outcome: str  # success | timeout | lost | error | the task's failure (e.g. collision)
    error: str = ""
    states: np.ndarray | None = None  # sim.state per frame, when recorded (for videos)
    data: dict[str, np.ndarray] | None = None  # every recorded frame, when the rollout is kept (--record)
    task: str = ""  # the member of a task set it ran in (demo.sim.foreign_set); "" for one environment
    instruction: str = ""  # what the episode was told (--instruction, else the environment's own); "" for none

    def to_json(self) -> dict[str, Any]:
        d = {
            "index": self.index,
            "seed": self.seed,
            "success": self.success,
            "length": self.length,
            "first_success_step": self.first_success_step,
            "outcome": self.outcome,
        }
        if self.error:
            d["error"] = self.error
        if self.task:
            d["task"] = self.task
        if self.instruction:
            d["instruction"] = self.instruction
        return d


# ---------------------------------------------------------------------------------- environment
def resolve_target(
    bundle: PolicyBundle, task: str | None, task_options: dict[str, Any] | None, robot: str | None
) -> tuple[str, dict[str, Any], Any]:
    """The task, task options and robot (a ``RobotConfig``) to evaluate on; refuses ones the policy was
    not trained for. ``robot`` (``--robot``): the name of a robot the run was trained on, or a robot
    config TOML; else the run's first robot, from the files the run (or its store's recorded source) carries."""
    where = str(bundle.path or "run")
    trained_task = bundle.task.get("name")
    trained_options = dict(bundle.task.get("options") or {})
    task = task or trained_task
    if not task:
        raise DemoError(where, "records no task; pass --task")
    foreign = is_foreign(task) and is_foreign(trained_task)  # another Gymnasium env with the same spaces may judge it
    if trained_task and task != trained_task and not foreign:
        raise DemoError(where, f"was trained on task {trained_task!r}; it cannot be evaluated on {task!r}")
    if foreign:  # a Gymnasium environment brings its own robot; its options are its own
        return task, trained_options if task_options is None else dict(task_options), None
    options = trained_options if task_options is None else {**trained_options, **task_options}
    wording = getattr(TASKS.get(task), "wording_options", ())  # e.g. held-out paraphrases of the instructions
    if trained_task and {k: v for k, v in options.items() if k not in wording} != \
            {k: v for k, v in trained_options.items() if k not in wording}:
        raise DemoError(
            where, f"was trained on {task} with options {trained_options}; it cannot be evaluated with {options}"
        )
    return task, options, pick_robot(bundle, robot)


def pick_robot(bundle: PolicyBundle, robot: str | None) -> Any:
    """The ``RobotConfig`` to evaluate on: the run's first robot, another it was trained on by name,
    or the robot config TOML ``robot`` (whether the policy may run on it is :func:`robot_transfer`'s call)."""
    records = trained_robots(bundle.run)
    names = [r.get("name") for r in records]
    if robot is None or (robot in names and not Path(robot).is_file()):
        i = 0 if robot is None else names.index(robot)
        return resolve_robot(records[i], None, robot_home(bundle.path, i))
    if not Path(robot).exists():
        raise DemoError(robot, f"no such robot config, nor a robot the run was trained on ({', '.join(map(str, names))})")
    return resolve_robot(None, robot)


def robot_transfer(bundle: PolicyBundle, robot: Any) -> str | None:
    """``None`` when the policy was trained on ``robot`` (a ``RobotConfig``; the same arm by content: its
    config keys and files, the name only a label), else the note saying it is new to the policy, where
    its actions allow it (end-effector space); refuses a joint-space policy."""
    records = trained_robots(bundle.run)
    mine = robot_record(robot)
    if not records or any(same_body(r, mine) for r in records):
        return None
    trained = [r.get("name") for r in records]
    where, action = str(bundle.path or "run"), bundle.action
    which = ", ".join(repr(n) for n in trained)
    if robot.name in trained:  # a name alone does not make an arm
        which += f" (another arm of the same name: its config or files differ from the run's {robot.name!r})"
    robot = robot.name
    if action.frame == "joint":
        raise DemoError(where, f"was trained on robot {which}; it cannot be evaluated on {robot!r}: its {action.name} "
                               "actions are joint targets of the arm it was trained on (a policy trained on actions "
                               "converted with `demo convert --to ee7` runs on other arms through their IK)")
    return (f"robot {robot!r} is not among the robots the policy was trained on ({which}); its {action.name} actions "
            "run through that arm's IK")


def judge_success(result: dict[str, Any], min_success: float | None = None) -> None:
    """After an evaluation's results are written: raise a :class:`DemoError` naming the run when the policy succeeded
    on none of its episodes on a robot it was not trained on (it cannot work that arm at all: its reach, its frames),
    or below ``min_success`` (a fraction in [0, 1]; ``demo eval --min-success``). A policy's 0% on the robot it was
    trained on is a result, not an error."""
    if min_success is not None and not 0.0 <= min_success <= 1.0:
        raise DemoError("--min-success", f"must be a fraction in [0, 1], got {min_success}")
    run, n = result["run"], result["episodes"]
    if result["successes"] == 0 and not result.get("robot_trained_on", True):
        raise DemoError(run, f"succeeded on none of {n} episodes on robot {result['robot']!r}, which it was not trained "
                             "on: check that arm with demo robot check (the results above are written)")
    if min_success is not None and result["success_rate"] < min_success:
        raise DemoError(run, f"success {result['success_rate']:.2f} < --min-success {min_success:g} over {n} episodes")


def make_eval_env(bundle: PolicyBundle, task: str, options: dict[str, Any], robot: Any, cameras: Sequence[Any] = ()) -> Any:
    """The task's environment for ``bundle`` on ``robot`` (a ``RobotConfig``), rendering the cameras its
    policy reads (and ``cameras``); refuses a robot the policy cannot run on (:func:`robot_transfer`).
    A Gymnasium environment (``env:...``) is rebuilt from its name and options alone."""
    if is_foreign(task):
        env = make_env(task, **options)
        try:
            bundle.obs_spec.check_against(env.features, f"{task} environment")
        except DemoError:
            env.close()
            raise
        return env
    env = make_env(task, robot=robot, cameras=[*bundle.obs_spec.cameras(), *cameras], **options)
    try:
        new = robot_transfer(bundle, env.robot)
        try:
            bundle.obs_spec.check_against(env.features, f"{task} environment (robot {env.robot.name})")
        except DemoError as exc:
            if new is None:
                raise
            raise DemoError(exc.where, f"{exc.problem} (a policy for several arms reads observations every arm "
                                       "reports, e.g. demo train --obs-keys obs.ee_pos,obs.ee_quat,obs.gripper,...)") from None
    except DemoError:
        env.close()
        raise
    return env


def make_actor(bundle: PolicyBundle, env: Any, execution: ExecConfig | None = None,
               instruction: str | None = None) -> PolicyActor:
    """The bundle's policy acting in ``env``; ``instruction``: told to every episode (an
    instruction-conditioned policy; None: each episode's environment's own)."""
    adapter = make_action_adapter(bundle.action, env, str(bundle.path or "run"))
    actor = bundle.actor(execution, adapter)
    actor.instruction = instruction
    return actor


# ---------------------------------------------------------------------------------- one episode
def run_episode(env: Any, actor: PolicyActor, index: int, seed: int, record: bool = False, max_steps: int | None = None,
                keep: bool = False) -> EpisodeOutcome:
    """Reset to ``seed`` and let the policy act until success has held or the horizon; ``record``: keep
    the states (videos), ``keep``: every frame (:attr:`EpisodeOutcome.data`). In a task set, episode ``index``
    runs in its member (:meth:`~demo.sim.foreign_set.ForeignEnvSet.select`)."""
    member = env.select(index) if isinstance(env, ForeignEnvSet) else None
    outcome = _run_episode(member or env, actor, index, seed, record, max_steps, keep)
    outcome.task = member.name if member is not None else ""
    outcome.instruction = actor.told
    return outcome


def _run_episode(env: Any, actor: PolicyActor, index: int, seed: int, record: bool, max_steps: int | None,
                 keep: bool) -> EpisodeOutcome:
    env.reset(seed)
    actor.reset(seed, env)

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        action = actor.act(frame)
        if not np.isfinite(action).all():
            raise FloatingPointError(f"non-finite action at step {t}")
        return StepCommand(executed=action, label=action)

    try:
        episode = rollout(env, seed, act, reset=False, record=record or keep, max_steps=max_steps)
    except FloatingPointError as exc:
        return EpisodeOutcome(index, seed, False, env.steps, None, "error", str(exc))
    if diverged(env):
        return EpisodeOutcome(index, seed, False, episode.length, None, "error", "simulation became unstable")
    if episode.success:
        outcome = "success"
    elif episode.failure:
        outcome = episode.failure
    elif episode.first_success_step is not None:
        outcome = "lost"
    else:
        outcome = "timeout"
    states = episode.data.get("sim.state") if record else None
    return EpisodeOutcome(index, seed, episode.success, episode.length, episode.first_success_step, outcome, "", states,
                          episode.data if keep else None)


def diverged(env: Any) -> bool:
    """MuJoCo resets the state itself on a bad acceleration and only counts a warning."""
    data = getattr(env, "data", None)
    if data is None:
        return False
    return int(data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number) > 0 or not np.isfinite(data.qpos).all()


def iter_episodes_inline(bundle: PolicyBundle, env: Any, jobs: Sequence[tuple[int, int, bool, bool]],
                         execution: ExecConfig | None = None, instruction: str | None = None) -> Iterator[EpisodeOutcome]:
    """Roll the policy out in this process, one ``(index, seed, record, keep)`` job after the other."""
    actor = make_actor(bundle, env, execution, instruction)
    with single_thread():
        for index, seed, record, keep in jobs:
            yield run_episode(env, actor, index, int(seed), record=record, keep=keep)


def run_episodes_inline(bundle: PolicyBundle, env: Any, seeds: Sequence[int],
                        execution: ExecConfig | None = None) -> list[EpisodeOutcome]:
    """Evaluate an in-memory policy in this process (training-time evaluation, benchmarks)."""
    return list(iter_episodes_inline(bundle, env, [(i, int(s), False, False) for i, s in enumerate(seeds)], execution))


class single_thread:
    """Context manager: torch on one thread (deterministic and fastest for batch-1 inference)."""

    def __enter__(self) -> None:
        self.threads = torch.get_num_threads()
        torch.set_num_threads(1)

    def __exit__(self, *exc: object) -> None:
        torch.set_num_threads(self.threads)


# ---------------------------------------------------------------------------------- workers (demo.executor)
_worker: dict[str, Any] = {}


def _worker_init(run: str, task: str, options: dict[str, Any], robot: str | None, execution: dict[str, Any],
                 device: str, randomize: dict[str, int] | None = None, instruction: str | None = None) -> None:
    torch.set_num_threads(1)
    bundle = load_bundle(run, device)
    env = one_member_at_a_time(make_eval_env(bundle, task, options, robot))
    if randomize:
        env.set_randomization(Randomization(randomize))
    _worker["env"] = env
    _worker["actor"] = make_actor(bundle, env, ExecConfig.from_json(execution), instruction)


def one_member_at_a_time(env: Any) -> Any:
    """``env``, a task set keeping one member built (:meth:`~demo.sim.foreign_set.ForeignEnvSet.keep_at_most`):
    an evaluation runs each member's episodes together, and from a camera every member built costs a renderer."""
    if isinstance(env, ForeignEnvSet):
        env.keep_at_most(1)
    return env


def _worker_run(job: tuple[int, int, bool, bool]) -> EpisodeOutcome:
    index, seed, record, keep = job
    return run_episode(_worker["env"], _worker["actor"], index, seed, record=record, keep=keep)


# ---------------------------------------------------------------------------------- the command
@dataclass
class EvalConfig:
    run: str
    task: str | None = None  # default: the task the policy was trained on
    task_options: dict[str, Any] | None = None  # default: the trained task's options
    robot: str | None = None  # robot config TOML; default: the trained robot
    episodes: int = 100
    seed: int = 0
    workers: int = 1  # 1: in this process (process executor)
    executor: str = "process"  # process | ray (demo.executor)
    address: str | None = None  # a Ray cluster (None: a local Ray)
    execute: int | None = None  # override the run's chunk execution
    ensemble: float | None = None  # override the ensembling decay (< 0 turns it off)
    candidates: int | None = None  # override the chunks drawn per query (coherent sampling, demo.policies.actor)
    video: str | None = None  # .gif (or .mp4 where an encoder is installed)
    video_episodes: int = 4
    video_size: int = 128
    device: str = "auto"  # where the policy runs (demo.policies.device); the simulation is always on the CPU
    record: str | None = None  # a store every rollout is appended to (created if absent): the flywheel
    randomize: dict[str, int] | None = None  # kind -> level (demo.sim.randomize): a distribution shift
    # told to every episode of an instruction-conditioned policy (None: each environment's own)
    instruction: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def check_told(bundle: PolicyBundle, instruction: str | None) -> list[str]:
    """Refuse an instruction for a policy that follows none (one line); the instruction's words its
    vocabulary lacks (each is read as unknown)."""
    if instruction is None:
        return []
    check_instruction(instruction)
    if bundle.tokenizer is None:
        raise DemoError("--instruction", f"{bundle.path or 'the run'}'s policy was trained without instructions "
                                         "and follows none")
    return bundle.tokenizer.unknown_words(instruction)


def execution_for(bundle: PolicyBundle, execute: int | None, ensemble: float | None,
                  candidates: int | None = None) -> ExecConfig:
    execution = dataclasses.replace(bundle.execution)
    if execute is not None:
        execution.execute = execute
    if ensemble is not None:
        execution.ensemble = None if ensemble < 0 else ensemble
    if candidates is not None:
        execution.candidates = candidates
    try:
        execution.check(bundle.policy.spec.horizon)
    except ValueError as exc:
        raise DemoError("--execute", str(exc)) from None
    return execution


def evaluate(config: EvalConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Evaluate the run at ``config.run``; returns the JSON-able result (see :func:`summarize`).

    ``progress`` gets a tick per finished episode (stage ``eval RUN``, field ``success`` so far)."""
    if config.episodes < 1:
        raise DemoError("--episodes", "must be at least 1")
    if config.workers < 1:
        raise DemoError("--workers", "must be at least 1")
    executor = ExecutorConfig(config.executor, config.workers, config.address)
    executor.check()
    run = Path(config.run)
    device = resolve_device(config.device)
    executor = executor.on_device(device)
    bundle = load_bundle(run, device)
    task, options, robot = resolve_target(bundle, config.task, config.task_options, config.robot)
    if config.video and is_foreign(task):
        raise DemoError("--video", "replays the simulator's recorded states; a Gymnasium environment's episodes have none")
    execution = execution_for(bundle, config.execute, config.ensemble, config.candidates)
    unknown = check_told(bundle, config.instruction)
    env = make_eval_env(bundle, task, options, robot)  # also validates before any worker starts
    if config.randomize:
        if is_foreign(task):
            env.close()
            raise DemoError("--shift", "changes demo's own scenes; a Gymnasium environment's are its own")
        env.set_randomization(Randomization(config.randomize))
    per_task = len(env.tasks) if isinstance(env, ForeignEnvSet) else 1  # --episodes is per task of a set
    seeds = eval_seeds(config.seed, config.episodes * per_task)
    n_video = min(config.video_episodes, config.episodes) if config.video else 0
    jobs = [(i, s, i < n_video, config.record is not None) for i, s in enumerate(seeds)]
    if per_task > 1:  # member by member, each worker one member built at a time
        jobs.sort(key=lambda job: (env.member_of(job[0]), job[0]))
        one_member_at_a_time(env)
    start = time.perf_counter()
    outcomes: list[EpisodeOutcome] = []
    tell = or_silent(progress)
    store: Any = None  # --record: the store each rollout is appended to, opened once the environment validates

    def done(outcome: EpisodeOutcome) -> None:
        if store is not None and outcome.data is not None:  # this process alone writes, in the jobs' order
            told = {"instruction": outcome.instruction} if outcome.instruction else {}
            store.append_episode(outcome.data, success=outcome.success, seed=outcome.seed, source="policy", **told,
                                 operator="policy", run=str(run), outcome=outcome.outcome,
                                 **({"task": outcome.task} if outcome.task else {}),
                                 first_success_step=-1 if outcome.first_success_step is None else outcome.first_success_step)
        outcome.data = None
        outcomes.append(outcome)
        successes = sum(o.success for o in outcomes)
        tell(Tick(f"eval {run.name}", len(outcomes), len(jobs), {"success": f"{successes}/{len(outcomes)}"}))

    robot_name = env.robot.name if env.robot is not None else None  # a Gymnasium environment has none of ours
    transfer = robot_transfer(bundle, env.robot) if env.robot is not None else None
    stack = ExitStack()  # an exception leaves the recorded episodes committed (a store created here and left empty goes)
    try:
        if config.record is not None:
            store = stack.enter_context(open_record(config.record, env, task, options, run, config.seed))
        if executor.kind == "process" and executor.workers == 1:
            for outcome in iter_episodes_inline(bundle, env, jobs, execution, config.instruction):
                done(outcome)
        else:
            init_args = (str(run), task, options, robot, execution.to_json(), str(device), config.randomize,
                         config.instruction)
            for ready in ordered_map(_worker_init, init_args, _worker_run, jobs, executor,
                                     label=lambda job: f"evaluation episode {job[0]}"):
                for outcome in ready:
                    done(outcome)
    except BaseException as exc:
        stack.__exit__(type(exc), exc, exc.__traceback__)
        raise
    finally:
        env.close()
    stack.close()
    seconds = time.perf_counter() - start
    outcomes.sort(key=lambda o: o.index)  # a set's ran member by member
    result = summarize(outcomes)
    if per_task > 1:
        result["per_task"] = {name: summarize([o for o in outcomes if o.task == name]) for name in env.tasks}
    training_seeds = set(int(s) for s in (bundle.run.get("data") or {}).get("seeds", []))
    result.update(
        {
            "run": str(run),
            "algo": bundle.algo,
            "task": task,
            "task_options": options,
            "robot": robot_name,
            "robot_trained_on": transfer is None,
            **({"robot_note": transfer} if transfer else {}),
            "seed": config.seed,
            "seed_rule": f"episode i starts from episode_seed(seed + {EVAL_OFFSET:_}, i) (demo.seeds)",
            "seeds_shared_with_training_data": len(training_seeds & set(seeds)),
            "execution": execution.to_json(),
            **({"randomize": config.randomize} if config.randomize else {}),
            **({"instruction": config.instruction, "unknown_words": unknown} if config.instruction else {}),
            "workers": config.workers,
            "executor": config.executor,
            "device": str(device),
            "seconds": seconds,
            "steps_per_s": sum(o.length for o in outcomes) / max(seconds, 1e-9),
            **config.extra,
        }
    )
    if store is not None:
        result["record"] = {"store": str(config.record), "episodes": sum(o.outcome != "error" for o in outcomes)}
    if config.video:
        recorded = [o for o in outcomes if o.states is not None]
        result["video"] = write_video(
            config.video, recorded, task, options, robot, fps=bundle.run.get("fps") or 20.0, size=config.video_size
        )
    result["episodes_detail"] = [o.to_json() for o in outcomes]
    return result


def open_record(path: str, env: Any, task: str, options: dict[str, Any], run: Path, seed: int) -> Any:
    """The store ``--record`` appends rollouts to (an :class:`EpisodeStore`, writer lock held): created
    with ``env``'s features, task and robot, or opened to append after checking it records the same
    (:func:`demo.store.output.open_output`; a mismatch is refused before any rollout)."""
    meta = env_store_meta(env, task, options, [{"op": "eval", "run": str(run), "seed": seed, "time": now()}])
    return open_output(path, meta, append=True, overwrite=False)


def summarize(outcomes: Sequence[EpisodeOutcome]) -> dict[str, Any]:
    n = len(outcomes)
    k = sum(o.success for o in outcomes)
    lo, hi = wilson_interval(k, n)
    lengths = np.array([o.length for o in outcomes], dtype=float)
    ok_lengths = np.array([o.length for o in outcomes if o.success], dtype=float)
    failures: dict[str, int] = {}
    for o in outcomes:
        if not o.success:
            failures[o.outcome] = failures.get(o.outcome, 0) + 1
    return {
        "episodes": n,
        "successes": k,
        "success_rate": k / n if n else 0.0,
        "ci95": [lo, hi],
        "mean_length": float(lengths.mean()) if n else None,
        "mean_length_success": float(ok_lengths.mean()) if len(ok_lengths) else None,
        "failures": failures,
    }
