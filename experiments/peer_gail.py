"""`demo bench peer-gail`: the ``imitation`` library's GAIL on a task's Gymnasium environment, as a peer
of ``demo irl train --algo gail`` (issue #20): same demonstrations, same evaluation episodes.
One file of ~570 lines on purpose: one experiment, read top to bottom (the peer's venv, the shared
demonstrations, the peer's run in its interpreter, ours, the comparison).

The peer runs in its own virtual environment, never in the project's: ``imitation`` 1.0.1 pins
``gymnasium~=0.29`` and ``stable-baselines3~=2.2.1`` where the project requires ``gymnasium>=1``
(docs/algorithms.md, Reinforcement and inverse RL)::

    python3 -m venv ../venv-imitation
    ../venv-imitation/bin/pip install -e .                   # demo and its dependencies (from the repository)
    ../venv-imitation/bin/pip install imitation==1.0.1       # downgrades gymnasium to 0.29.1

(pip reports that demo-toolkit wants gymnasium>=1.0; ``demo.gym`` runs on 0.29.1, whose API it uses.)
This module imports ``imitation`` and ``stable_baselines3`` only inside :func:`run`; without them it
raises one DemoError line saying how to install them.

What it does, in order:

1. **Demonstrations** (:func:`load_demonstrations`): the first ``demos`` successful episodes of the
   store ``data``, as imitation ``Trajectory`` s. Observations are flattened exactly as the env's
   ``gymnasium.wrappers.FlattenObservation`` flattens them (``gymnasium.spaces.flatten`` of the
   env's ``Dict`` space: its keys in the space's order, alphabetical, each key's array row-major;
   the store's ``obs.*`` features hold the same values per frame). Actions are the store's, in its
   representation, which the env is made with (``action=``, ``rotation=``, ``delta_frame=``):
   ``joint_pos`` by default, absolute arm joint targets (rad) + gripper closedness (0..1), clipped to
   the env's action ``Box`` as stable-baselines3 clips what a policy executes. A demonstration ends
   once success has held 0.5 s (reach: ~27 of 100 steps); imitation's GAIL wants episodes of one
   length (its variable-horizon guide), so each is padded to the task's horizon by repeating its
   last frame and action, the settled expert holding still: the absorbing state of seals'
   ``AbsorbAfterDoneWrapper``, and what ``demo irl train``'s horizon weight on the last transition
   stands for (:mod:`demo.rl.expert_data`).
2. **Training**: imitation's ``GAIL`` with stable-baselines3's ``PPO`` on ``envs`` copies of
   ``demo/<Task>-v0`` in a ``DummyVecEnv`` (one process, stepped in turn), with
   ``hold_success_s=None`` so that every training episode runs to the horizon (fixed length, as
   imitation requires and as ``demo irl train`` does). Every training episode starts from the next
   seed of the RL stream, ``episode_seed(seed + RL_OFFSET, i)`` (:mod:`demo.seeds`), whatever seed
   stable-baselines3 passes to ``reset``: disjoint from collection and evaluation. ``steps`` is an
   upper bound: imitation trains ``steps // (envs * rollout)`` rounds, each one PPO rollout of
   ``envs * rollout`` environment steps, its discriminator updates and a PPO update; the environment
   steps actually taken are counted and reported. The loop is ``AdversarialTrainer.train``'s own,
   called as is; only its tqdm bar is swapped for this command's progress.
3. **Evaluation**: the learned policy's deterministic (mean) action on exactly the episodes of
   ``demo eval --seed seed --episodes eval_episodes``: reset seeds :func:`demo.seeds.eval_seeds`, the
   env's default ending rule (success held 0.5 s, or the task's horizon; the rule ``demo eval``'s
   rollout loop ends episodes by). Success is ``info["success"]`` after the last step, the task's
   predicate at the end: what ``demo eval`` counts (``env.success()`` after the last step). Outcomes
   as ``demo eval`` names them (success, timeout, lost, the task's failure, error), with a 95% Wilson
   interval (:func:`demo.evaluation.evaluate.wilson_interval`).

Hyper-parameters (:class:`PeerGailConfig`): imitation's own GAIL tutorial ("Train an Agent using
Generative Adversarial Imitation Learning", ``docs/tutorials/3_train_gail.ipynb``, seals/CartPole-v0
with 8 environments): ``PPO(MlpPolicy, batch_size=64, ent_coef=0.0, learning_rate=4e-4, gamma=0.95,
n_epochs=5)`` (``n_steps``, the rollout per environment, left at stable-baselines3's 2048), the
discriminator ``BasicRewardNet(normalize_input_layer=RunningNorm)``, ``GAIL(demo_batch_size=1024,
gen_replay_buffer_capacity=512, n_disc_updates_per_round=8)``. Nothing was tuned for our tasks.

Units: observations in the store's units (m, rad, rad/s, quaternions wxyz, robot base frame),
actions in the representation's (``joint_pos``: rad); steps are control steps (20 Hz); times in
seconds (wall: ``time.perf_counter``; CPU: this process's user + system time, all its threads).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.metadata
import platform
import tempfile
import time
import types
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np
import torch

from demo.bench.common import machine
from demo.errors import DemoError
from demo.evaluation.evaluate import diverged, wilson_interval
from demo.gym import env_id  # importing demo.gym registers the demo/<Task>-v0 ids
from demo.progress import Progress, Tick, or_silent
from demo.seeds import EVAL_OFFSET, RL_OFFSET, episode_seed, eval_seeds
from demo.sim.robot_record import BUILTIN, resolve_robot
from demo.sim.tasks import TASK_NAMES
from demo.store import EpisodeStore

INSTALL = ("in the repository: python3 -m venv ../venv-imitation && ../venv-imitation/bin/pip install -e . && "
           "../venv-imitation/bin/pip install imitation==1.0.1, then run ../venv-imitation/bin/demo "
           "(README: the peer GAIL)")
HP_SOURCE = ("imitation's GAIL tutorial (docs/tutorials/3_train_gail.ipynb, seals/CartPole-v0, 8 envs): "
             "PPO(MlpPolicy, batch_size=64, ent_coef=0.0, learning_rate=4e-4, gamma=0.95, n_epochs=5; n_steps "
             "SB3's default 2048), BasicRewardNet(normalize_input_layer=RunningNorm), GAIL(demo_batch_size=1024, "
             "gen_replay_buffer_capacity=512, n_disc_updates_per_round=8); not tuned for our tasks")
PACKAGES = ("imitation", "stable-baselines3", "gymnasium", "torch", "numpy", "mujoco", "demo-toolkit")


@dataclass
class PeerGailConfig:
    """One peer run. The defaults after ``threads`` are imitation's GAIL tutorial's (module docstring)."""

    data: str = ""  # the demonstrations: a store of ``task``
    task: str = "reach"
    demos: int | None = None  # the first N successful episodes (default all)
    steps: int = 480_000  # environment (control) steps of training, an upper bound (whole rounds)
    seed: int = 0  # PPO, the discriminator, the RL seed stream and the evaluation episodes
    eval_episodes: int = 100
    envs: int = 8  # environments in the DummyVecEnv
    rollout: int = 2048  # PPO n_steps: control steps per environment per round
    threads: int = 1  # torch threads
    # PPO (stable-baselines3)
    batch_size: int = 64  # PPO minibatch
    learning_rate: float = 4e-4
    gamma: float = 0.95
    n_epochs: int = 5
    ent_coef: float = 0.0
    # GAIL (imitation)
    demo_batch_size: int = 1024  # expert (and as many policy) samples per discriminator update
    gen_replay_buffer_capacity: int = 512
    n_disc_updates_per_round: int = 8

    def check(self) -> None:
        positive = {"--steps": self.steps, "--eval-episodes": self.eval_episodes, "--envs": self.envs,
                    "--rollout": self.rollout, "--threads": self.threads, "--demo-batch-size": self.demo_batch_size,
                    "batch_size": self.batch_size, "n_epochs": self.n_epochs,
                    "gen_replay_buffer_capacity": self.gen_replay_buffer_capacity,
                    "n_disc_updates_per_round": self.n_disc_updates_per_round}
        for flag, value in positive.items():
            if value < 1:
                raise DemoError(flag, f"must be at least 1, got {value}")
        if self.demos is not None and self.demos < 1:
            raise DemoError("--demos", f"must be at least 1, got {self.demos}")
        if self.steps < self.round_steps:
            raise DemoError("--steps", f"{self.steps:,} is less than one GAIL round (--envs {self.envs} x --rollout "
                                       f"{self.rollout} = {self.round_steps:,} environment steps)")
        if not self.data:
            raise DemoError("--data", "name the store of demonstrations")

    @property
    def round_steps(self) -> int:
        """Environment steps of one GAIL round (one PPO rollout)."""
        return self.envs * self.rollout

    @property
    def rounds(self) -> int:
        return self.steps // self.round_steps

    def hyperparameters(self) -> dict[str, Any]:
        return {
            "ppo": {"policy": "MlpPolicy", "n_steps": self.rollout, "n_envs": self.envs, "batch_size": self.batch_size,
                    "learning_rate": self.learning_rate, "gamma": self.gamma, "n_epochs": self.n_epochs,
                    "ent_coef": self.ent_coef, "other": "stable-baselines3 defaults"},
            "reward_net": {"class": "BasicRewardNet", "normalize_input_layer": "RunningNorm", "other": "imitation defaults"},
            "gail": {"demo_batch_size": self.demo_batch_size, "gen_replay_buffer_capacity": self.gen_replay_buffer_capacity,
                     "n_disc_updates_per_round": self.n_disc_updates_per_round, "allow_variable_horizon": False},
            "source": HP_SOURCE,
        }


# ====================================================================================== the environment
@dataclass
class EnvSpec:
    """How ``demo/<Task>-v0`` is made for the store's demonstrations (``gymnasium.make`` keyword arguments)."""

    env_id: str
    options: dict[str, Any]  # action, rotation, delta_frame, task options, robot (None: built-in)
    robot_name: str

    def make(self, training: bool = False) -> gymnasium.Env:
        """The env wrapped in ``FlattenObservation``: for evaluation, its own ending rule (success held
        0.5 s, or the horizon); for ``training``, ``hold_success_s=None`` (every episode runs to the horizon)."""
        extra = {"hold_success_s": None} if training else {}
        # store_layout: the observation keys are the store's feature names, which the demonstrations are read by.
        return gymnasium.wrappers.FlattenObservation(gymnasium.make(self.env_id, **self.options, store_layout=True,
                                                                    **extra))

    def to_json(self) -> dict[str, Any]:
        return {"env_id": self.env_id, "robot": self.robot_name,
                **{k: v for k, v in self.options.items() if k != "robot"}}


class SeedStream:
    """The reset seeds of a run's training episodes: ``episode_seed(seed + RL_OFFSET, i)`` for i = 0, 1, ...
    in the order episodes start, shared by every environment of the vector env."""

    def __init__(self, seed: int):
        self.seed = seed
        self.used: list[int] = []

    def next(self) -> int:
        s = episode_seed(self.seed + RL_OFFSET, len(self.used))
        self.used.append(s)
        return s


class StreamSeeded(gymnasium.Wrapper):
    """Every ``reset`` from the next seed of ``stream`` (the seed a caller passes is ignored); counts the
    control steps taken (:attr:`steps`)."""

    def __init__(self, env: gymnasium.Env, stream: SeedStream):
        super().__init__(env)
        self.stream = stream
        self.steps = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        return self.env.reset(seed=self.stream.next(), options=options)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        self.steps += 1
        return self.env.step(action)


def env_spec_for(store: Any, path: str, task: str) -> EnvSpec:
    """The env that executes the store's actions and observes what the store recorded; refuses a store of
    another task, an action representation the env cannot take, or missing observation features."""
    if task not in TASK_NAMES:
        raise DemoError("--task", f"unknown task {task!r} (choose from {', '.join(TASK_NAMES)})")
    meta = store.meta
    have = (meta.task or {}).get("name")
    if have != task:
        raise DemoError(path, f"holds {have!r} demonstrations, not {task!r} (--task)")
    action = meta.action
    options: dict[str, Any] = {"action": action.name, **dict((meta.task or {}).get("options") or {})}
    for key in ("rotation", "delta_frame"):
        if action.params.get(key):
            options[key] = action.params[key]
    record = meta.robot or {}
    if record.get("config") != BUILTIN:
        options["robot"] = resolve_robot(record, None, path)
    return EnvSpec(env_id(task), options, str(record.get("name", "builtin")))


def check_env_against(env: gymnasium.Env, store: Any, path: str) -> list[str]:
    """The env's observation keys (in the flattening order); a DemoError where the store does not record
    them with the same shapes or holds another action representation."""
    inner = env.unwrapped
    meta = store.meta
    if inner.action_spec.name != meta.action.name or inner.action_spec.dim != meta.action.dim:
        raise DemoError(path, f"holds {meta.action.name} actions ({meta.action.dim}); the env acts in "
                              f"{inner.action_spec.name} ({inner.action_spec.dim})")
    space = inner.observation_space
    keys = list(space.spaces)
    missing = [k for k in keys if k not in meta.features]
    if missing:
        raise DemoError(path, f"does not record {', '.join(missing)}, which the env observes")
    wrong = [k for k in keys if int(np.prod(meta.features[k].shape)) != int(np.prod(space[k].shape))]  # both flattened
    if wrong:
        raise DemoError(path, f"records {', '.join(wrong)} in another shape than the env observes")
    return keys


# ====================================================================================== demonstrations
@dataclass
class Demonstrations:
    """Demonstrations in the flattened env's terms, one entry per episode, padded to ``horizon``."""

    obs: list[np.ndarray]  # [horizon + 1, D] each: the frames, then the last repeated
    acts: list[np.ndarray]  # [horizon, A] each: the actions, then the last repeated
    lengths: list[int]  # recorded frames (= actions) of each episode before padding
    seeds: list[int]  # the episodes' reset seeds
    episodes: list[int]  # their indices in the store
    clipped: int  # action entries outside the env's Box (clipped into it)

    @property
    def transitions(self) -> int:
        return int(sum(len(a) for a in self.acts))

    def record(self, path: str) -> dict[str, Any]:
        return {"path": path, "episodes": len(self.lengths), "store_episodes": self.episodes, "seeds": self.seeds,
                "recorded_transitions": int(sum(self.lengths)), "padded_transitions": self.transitions,
                "mean_length": float(np.mean(self.lengths)), "actions_clipped": self.clipped}


def flatten_frames(space: gymnasium.spaces.Dict, frames: dict[str, np.ndarray]) -> np.ndarray:
    """``[T, D]``: each of ``T`` frames (``{key: [T, ...]}``) as ``gymnasium.spaces.flatten(space, frame)``,
    which is what ``FlattenObservation`` returns for it."""
    n = len(next(iter(frames.values())))
    return np.stack([gymnasium.spaces.flatten(space, {k: frames[k][t] for k in space.spaces}) for t in range(n)])


def load_demonstrations(store: Any, path: str, env: gymnasium.Env, demos: int | None) -> Demonstrations:
    """The first ``demos`` (default all) successful episodes of ``store`` for the flattened ``env``
    (module docstring: flattening, actions, padding to ``env.unwrapped.horizon``)."""
    inner = env.unwrapped
    keys = check_env_against(env, store, path)
    chosen = np.flatnonzero(store.column("success").astype(bool))
    if demos is not None:
        if demos > len(chosen):
            raise DemoError("--demos", f"{path} has {len(chosen)} successful episodes; asked for {demos}")
        chosen = chosen[:demos]
    if len(chosen) == 0:
        raise DemoError(path, "has no successful episodes to learn from")
    horizon = int(inner.horizon)
    low, high = env.action_space.low, env.action_space.high
    seeds = store.column("seed")
    out = Demonstrations([], [], [], [], [], 0)
    for index in chosen:
        data = store.read_episode(int(index), [*keys, "action"])
        n = len(data["action"])
        if n < 1 or n > horizon:
            raise DemoError(path, f"episode {int(index)} has {n} frames; the {inner.spec.id if inner.spec else 'task'} "
                                  f"horizon is {horizon}")
        obs = flatten_frames(inner.observation_space, data).astype(env.observation_space.dtype)
        act = np.asarray(data["action"], dtype=env.action_space.dtype)
        out.clipped += int(((act < low) | (act > high)).sum())
        act = np.clip(act, low, high)
        out.obs.append(np.concatenate([obs, np.repeat(obs[-1:], horizon + 1 - n, axis=0)]))
        out.acts.append(np.concatenate([act, np.repeat(act[-1:], horizon - n, axis=0)]))
        out.lengths.append(n)
        out.seeds.append(int(seeds[index]))
        out.episodes.append(int(index))
    return out


# ====================================================================================== evaluation
def evaluate(env: gymnasium.Env, act: Callable[[np.ndarray], np.ndarray], seeds: Sequence[int],
             progress: Progress | None = None) -> list[dict[str, Any]]:
    """Roll ``act`` (a flattened observation -> an action of the env's space) out from each reset seed in
    ``seeds`` on ``env`` (the env's own ending rule); one record per episode, ``demo eval``'s fields."""
    tick = or_silent(progress)
    episodes = []
    for i, seed in enumerate(seeds):
        obs, info = env.reset(seed=int(seed))
        length, first_success, outcome, error = 0, None, None, ""
        while True:
            action = np.asarray(act(obs))
            if not np.isfinite(action).all():
                outcome, error = "error", f"non-finite action at step {length}"
                break
            obs, _, terminated, truncated, info = env.step(action)
            length += 1
            if info["success"] and first_success is None:
                first_success = length
            if terminated or truncated:
                break
        sim = env.unwrapped.sim
        if outcome is None and diverged(sim):
            outcome, error = "error", "simulation became unstable"
        success = outcome is None and bool(info["success"])
        if outcome is None:
            failure = info.get("failure")
            outcome = "success" if success else failure if failure else "lost" if first_success is not None else "timeout"
        record = {"index": i, "seed": int(env.unwrapped.reset_seed), "success": success, "length": length,
                  "first_success_step": first_success, "outcome": outcome}
        if error:
            record["error"] = error
        episodes.append(record)
        tick(Tick("peer-gail eval", done=i + 1, total=len(seeds),
                  fields={"success": f"{sum(e['success'] for e in episodes)}/{i + 1}"}))
    return episodes


# ====================================================================================== the run
def require_peer() -> tuple[Any, Any]:
    """``(imitation, stable_baselines3)``, or one DemoError line saying how to install them."""
    try:
        import imitation  # deferred: optional dependency (the imitation venv)
        import stable_baselines3  # deferred: optional dependency (the imitation venv)
    except ImportError as exc:
        raise DemoError("imitation", f"not importable in this Python ({exc.name or exc}); the peer GAIL runs in its "
                                     f"own venv: {INSTALL}") from None
    return imitation, stable_baselines3


def versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


@contextlib.contextmanager
def _quiet_rounds(module: Any) -> Iterator[None]:
    """``AdversarialTrainer.train`` without its tqdm bar (this command draws its own progress)."""
    before = module.tqdm
    module.tqdm = types.SimpleNamespace(tqdm=lambda iterable, **_: iterable)
    try:
        yield
    finally:
        module.tqdm = before


@contextlib.contextmanager
def _torch_threads(n: int) -> Iterator[None]:
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


class _Clock:
    """Wall (``perf_counter``) and CPU (this process, all threads) seconds since it was made."""

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def read(self) -> dict[str, float]:
        return {"wall_s": time.perf_counter() - self.wall, "cpu_s": time.process_time() - self.cpu}


def run(config: PeerGailConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Train imitation's GAIL on the store's demonstrations and evaluate it on ``demo eval``'s episodes;
    the JSON-able result (module docstring)."""
    config.check()
    require_peer()
    from imitation.algorithms.adversarial import common as adversarial_common  # deferred: optional dependency (the imitation venv)
    from imitation.algorithms.adversarial.gail import GAIL  # deferred: optional dependency (the imitation venv)
    from imitation.data.types import Trajectory  # deferred: optional dependency (the imitation venv)
    from imitation.rewards.reward_nets import BasicRewardNet  # deferred: optional dependency (the imitation venv)
    from imitation.util import logger as imitation_logger  # deferred: optional dependency (the imitation venv)
    from imitation.util.networks import RunningNorm  # deferred: optional dependency (the imitation venv)
    from stable_baselines3 import PPO  # deferred: optional dependency (the imitation venv)
    from stable_baselines3.common.utils import set_random_seed  # deferred: optional dependency (the imitation venv)
    from stable_baselines3.common.vec_env import DummyVecEnv  # deferred: optional dependency (the imitation venv)

    tick = or_silent(progress)
    total = _Clock()
    with EpisodeStore.open(config.data) as store:
        spec = env_spec_for(store, config.data, config.task)
        probe = spec.make(training=True)
        try:
            demos = load_demonstrations(store, config.data, probe, config.demos)  # checks the env against the store
            keys = list(probe.unwrapped.observation_space.spaces)  # the flattening order
            obs_space, act_space, horizon = probe.observation_space, probe.action_space, int(probe.unwrapped.horizon)
        finally:
            probe.close()
    if demos.transitions < config.demo_batch_size:
        raise DemoError("--demo-batch-size", f"{config.demo_batch_size} is more than the {demos.transitions} "
                                             f"demonstration transitions ({len(demos.lengths)} episodes x {horizon} steps)")
    trajectories = [Trajectory(obs=o, acts=a, infos=None, terminal=True) for o, a in zip(demos.obs, demos.acts)]

    stream = SeedStream(config.seed)
    envs: list[StreamSeeded] = []

    def make_training_env() -> gymnasium.Env:
        env = StreamSeeded(spec.make(training=True), stream)
        envs.append(env)
        return env

    rounds: list[dict[str, Any]] = []
    with _torch_threads(config.threads), tempfile.TemporaryDirectory(prefix="peer-gail-") as scratch:
        set_random_seed(config.seed)
        venv = DummyVecEnv([make_training_env] * config.envs)
        try:
            learner = PPO(env=venv, policy="MlpPolicy", n_steps=config.rollout, batch_size=config.batch_size,
                          ent_coef=config.ent_coef, learning_rate=config.learning_rate, gamma=config.gamma,
                          n_epochs=config.n_epochs, seed=config.seed, device="cpu", verbose=0)
            reward_net = BasicRewardNet(observation_space=venv.observation_space, action_space=venv.action_space,
                                        normalize_input_layer=RunningNorm)
            trainer = GAIL(demonstrations=trajectories, demo_batch_size=config.demo_batch_size,
                           gen_replay_buffer_capacity=config.gen_replay_buffer_capacity,
                           n_disc_updates_per_round=config.n_disc_updates_per_round, venv=venv, gen_algo=learner,
                           reward_net=reward_net, log_dir=scratch,
                           custom_logger=imitation_logger.configure(scratch, format_strs=[]))
            train_clock = _Clock()

            def after_round(r: int) -> None:
                values = trainer.logger.default_logger.name_to_value
                stats = {k.removeprefix("mean/"): float(v) for k, v in values.items()
                         if k.startswith(("mean/disc/", "mean/gen/")) and not k.startswith("mean/gen/time/")}
                steps = sum(e.steps for e in envs)
                rounds.append({"round": r + 1, "env_steps": steps, **stats})
                tick(Tick("peer-gail train", done=steps, total=config.rounds * config.round_steps,
                          fields={"round": f"{r + 1}/{config.rounds}",
                                  "disc acc expert": f"{stats.get('disc/disc_acc_expert', float('nan')):.2f}",
                                  "disc acc policy": f"{stats.get('disc/disc_acc_gen', float('nan')):.2f}"}))

            try:
                with _quiet_rounds(adversarial_common):
                    trainer.train(config.steps, callback=after_round)
            except ValueError as exc:
                if "different length" in str(exc):  # a task that ends episodes on failure (avoid's collision)
                    raise DemoError(config.task, "training episodes of different lengths (the task ended one "
                                                 "early); imitation's GAIL here needs a fixed horizon") from None
                raise
            training = {**train_clock.read(), "env_steps": sum(e.steps for e in envs), "rounds": len(rounds),
                        "reset_seeds_drawn": len(stream.used)}
        finally:
            venv.close()

        seeds = eval_seeds(config.seed, config.eval_episodes)
        policy = learner.policy
        eval_clock = _Clock()
        env = spec.make()
        try:
            episodes = evaluate(env, lambda o: policy.predict(o, deterministic=True)[0], seeds, progress)
        finally:
            env.close()
        eval_steps = sum(e["length"] for e in episodes)
    successes = sum(e["success"] for e in episodes)
    failures: dict[str, int] = {}
    for e in episodes:
        if not e["success"]:
            failures[e["outcome"]] = failures.get(e["outcome"], 0) + 1
    data_seeds = set(demos.seeds)
    train_seeds = set(stream.used)
    low, high = wilson_interval(successes, len(episodes))
    evaluation = {
        **eval_clock.read(), "episodes": len(episodes), "successes": successes,
        "success_rate": successes / len(episodes), "ci95": [low, high], "failures": failures,
        "mean_length": float(np.mean([e["length"] for e in episodes])), "env_steps": eval_steps,
        "seeds": [int(s) for s in seeds],
        "seed_stream": f"demo eval --seed {config.seed}: episode_seed({config.seed} + {EVAL_OFFSET:_}, i)",
        "seed_overlap_with_data": len(set(seeds) & data_seeds),
        "episodes_detail": episodes,
    }
    training.update({
        # imitation's GAIL resets the vector env once when it wraps it, and stable-baselines3 again before its
        # first rollout: the first `envs` seeds start episodes that take no step.
        "seed_stream": f"episode_seed({config.seed} + {RL_OFFSET:_}, i), i = 0 .. {len(stream.used) - 1}",
        "seed_overlap_with_data": len(train_seeds & data_seeds),
        "seed_overlap_with_eval": len(train_seeds & set(seeds)),
        "per_round": rounds,
    })
    clock = total.read()
    return {
        "benchmark": "peer-gail",
        "peer": "imitation GAIL + stable-baselines3 PPO",
        "task": config.task,
        "env": {**spec.to_json(), "training_hold_success_s": None, "eval_hold_success_s": "the env's default (0.5 s)",
                "horizon": horizon},
        "observation": {"keys": keys, "dim": int(obs_space.shape[0]),
                        "flatten": "gymnasium.wrappers.FlattenObservation (spaces.flatten: Dict keys in the space's "
                                   "order, each row-major)"},
        "action": {"name": spec.options["action"], "dim": int(act_space.shape[0]),
                   "low": act_space.low.tolist(), "high": act_space.high.tolist()},
        "data": demos.record(config.data),
        "seed": config.seed,
        "success_rate": evaluation["success_rate"],
        "ci95": evaluation["ci95"],
        "successes": successes,
        "eval_episodes": len(episodes),
        "env_steps": training["env_steps"] + eval_steps,
        "train_env_steps": training["env_steps"],
        "wall_s": clock["wall_s"],
        "cpu_s": clock["cpu_s"],
        "training": training,
        "eval": evaluation,
        "config": dataclasses.asdict(config),
        "hyperparameters": config.hyperparameters(),
        "versions": versions(),
        "machine": {**machine(), "torch_threads": config.threads},
    }


def summary_rows(result: dict[str, Any]) -> list[tuple[str, Any]]:
    """The CLI table's rows."""
    ev, tr, data = result["eval"], result["training"], result["data"]
    lo, hi = ev["ci95"]
    failures = ", ".join(f"{k} {v}" for k, v in sorted(ev["failures"].items())) or "-"
    return [
        ("demonstrations", f"{data['episodes']} episodes of {data['path']} ({data['recorded_transitions']} transitions, "
                           f"padded to {data['padded_transitions']})"),
        ("success (demo eval's episodes)", f"{ev['successes']}/{ev['episodes']} ({ev['success_rate']:.0%}, "
                                           f"95% CI {lo:.0%}-{hi:.0%})"),
        ("failures", failures),
        ("training env steps", f"{tr['env_steps']:,} in {tr['rounds']} rounds ({tr['reset_seeds_drawn']:,} reset seeds "
                               "of the RL stream)"),
        ("env steps in all", f"{result['env_steps']:,}"),
        ("training s (wall / CPU)", f"{tr['wall_s']:.1f} / {tr['cpu_s']:.1f}"),
        ("eval s (wall / CPU)", f"{ev['wall_s']:.1f} / {ev['cpu_s']:.1f}"),
        ("seed overlaps (eval-data, train-data, train-eval)",
         f"{ev['seed_overlap_with_data']}, {tr['seed_overlap_with_data']}, {tr['seed_overlap_with_eval']}"),
        ("versions", ", ".join(f"{k} {v}" for k, v in result["versions"].items() if k in ("imitation", "stable-baselines3",
                                                                                             "gymnasium", "torch"))),
    ]
