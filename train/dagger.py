"""DAgger (Ross, Gordon & Bagnell 2011) and HG-DAgger (Kelly et al. 2019) with the tasks' experts.

``demo train DATA --algo dagger --task T --rounds R --episodes-per-round K`` runs :func:`train_dagger`:

0. DATA's episodes are copied into the run's own store ``RUN/data.zarr`` (DATA is never modified),
   with a per-frame flag ``info.labelled``; round 0 trains behaviour cloning on them exactly as
   ``--algo bc`` would (the shared :class:`demo.train.trainer.TrainingRun`).
1. Round ``r = 1..R`` rolls out ``K`` episodes (seeds: :mod:`demo.seeds`) of the mixture
   policy: at every step the expert is asked for its action on the visited state (the task experts
   are state-feedback policies, so any state can be labelled), and the executed action is the
   expert's with probability ``beta_r``, else the learner's. ``--beta``:

   - ``indicator``: ``beta_r = 0`` (round 0 already was the expert's data; Ross et al.'s choice);
   - ``linear:N``: ``beta_r = max(0, 1 - r / N)``;
   - ``exp:P``: ``beta_r = P ** r``.

   With ``--gate deviation:THRESH`` (HG-DAgger) the learner drives; the expert takes over when the
   learner's arm joint targets differ from its own by more than THRESH rad (max over joints), or
   its gripper command by more than :data:`GRIPPER_GATE`, and hands back once they agree within
   THRESH/2 (hysteresis, as a person would); only the frames it was in control of become labels.
2. The episodes are appended to ``RUN/data.zarr`` (source ``dagger``, columns ``dagger_round``,
   ``labels``), each visited state labelled by the expert (``action``), the executed action in
   ``info.executed_action``.
3. A new learner is trained for ``round_steps`` on the aggregate (Ross et al.'s "train on D") with
   round 0's normalisers, fitted on the demonstrations: an early learner's rollouts flail (joints to
   their limits, the EE half a metre up), and min-max ranges refitted to them leave the states that
   matter a fraction of the input range (on ``stack``, the joint ranges were 4x wider after the
   rounds; inputs outside the demonstrations' ranges are clipped, see
   :data:`demo.train.normalizer.OBS_CLIP`).
   ``refit_normalizers`` refits them to the aggregate instead; ``warm_start`` fine-tunes the
   previous learner instead of training a new one (cheaper).

Expert labels are counted: every frame of DATA's episodes that training used (validation
included) plus every labelled frame of every round, so comparisons with BC can be made at equal
label budgets (``metrics.json`` ``rounds[*].labels_total``). DART-style data (collected with
``--noise``: noise on the executed action, clean labels) trains with ``--algo bc`` and the same
label accounting.

``--resume`` continues at the round where a run stopped (a round's rollouts already in the store
are reused, not repeated).

The learner is BC's policy, single-step unless told otherwise (:data:`demo.train.config.DAGGER_DEFAULTS`).
Everything else of a run (seeding, the run directory, the loop, checkpoints, metrics) is the shared
:class:`demo.train.trainer.TrainingRun`'s; this file holds only what is DAgger's own.
"""

from __future__ import annotations

import dataclasses
from contextlib import ExitStack, closing
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.progress import Progress
from demo.seeds import dagger_seeds
from demo.sim.rollout import StepCommand, rollout
from demo.store import EpisodeStore, FeatureSpec, StoreMeta
from demo.train import checkpoint as ckpt
from demo.train.config import DAGGER_DEFAULTS, TrainConfig, for_policy
from demo.train.data import LABEL_KEY, TrainingData, prepare
from demo.train.evaluate import make_actor, single_thread
from demo.train.optim import Learner
from demo.train.trainer import TrainingRun

DATA_DIR = "data.zarr"
GRIPPER_GATE = 0.5  # HG-DAgger: a gripper command this far (of 0 open .. 1 closed) from the expert's is a deviation


@dataclass
class DaggerConfig:
    """DAgger's own hyperparameters; ``train`` holds round 0's (and the optimiser's)."""

    train: TrainConfig = field(default_factory=TrainConfig)
    task: str | None = None  # must be the data's task (default)
    rounds: int = 5
    episodes_per_round: int = 10
    round_steps: int = 2000
    warm_start: bool = False  # fine-tune the previous learner instead of training a new one each round
    refit_normalizers: bool = False  # refit the normalisers to each round's aggregate (default: keep the demonstrations')
    beta: str = "indicator"  # indicator | linear:N | exp:P
    gate: str | None = None  # deviation:THRESH (rad) for HG-DAgger

    def beta_at(self, r: int) -> float:
        kind, _, arg = self.beta.partition(":")
        try:
            if kind == "indicator" and not arg:
                return 0.0
            if kind == "linear":
                return max(0.0, 1.0 - r / float(arg))
            if kind == "exp":
                return float(arg) ** r
        except ValueError:
            pass
        raise DemoError("--beta", f"{self.beta!r} is not indicator, linear:N or exp:P")

    def gate_threshold(self) -> float | None:
        if self.gate is None:
            return None
        kind, _, arg = self.gate.partition(":")
        try:
            value = float(arg)
        except ValueError:
            value = -1.0
        if kind != "deviation" or value <= 0:
            raise DemoError("--gate", f"{self.gate!r} is not deviation:THRESH with THRESH > 0 (rad)")
        return value

    def check(self) -> None:
        self.train.check()
        if self.rounds < 0:
            raise DemoError("--rounds", f"must be >= 0, got {self.rounds}")
        if self.episodes_per_round < 1:
            raise DemoError("--episodes-per-round", f"must be at least 1, got {self.episodes_per_round}")
        if self.round_steps < 1:
            raise DemoError("--round-steps", f"must be at least 1, got {self.round_steps}")
        self.beta_at(1)
        self.gate_threshold()
        b = self.beta_at(1)
        if not 0 <= b <= 1:
            raise DemoError("--beta", f"beta must lie in [0, 1], got {b} in round 1")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["train"] = self.train.to_json()
        return d


def learner_config(**given: Any) -> TrainConfig:
    """The learner's resolved config: ``given`` values, then :data:`DAGGER_DEFAULTS`, then the policy's."""
    given = {k: v for k, v in given.items() if v is not None}
    return for_policy(given.pop("algo", "bc"), **{**DAGGER_DEFAULTS, **given})


# ================================================================================== the aggregate store
def create_aggregate(source: EpisodeStore, path: Path) -> EpisodeStore:
    """A copy of ``source`` with the per-frame ``info.labelled`` flag (all True for its episodes)."""
    meta = StoreMeta.from_json(source.meta.to_json())
    meta.features[LABEL_KEY] = FeatureSpec((), "uint8", "1 where the action is an expert label", "")
    meta.provenance = [*meta.provenance, {"op": "dagger", "from": str(source.path), "time": ckpt.now()}]
    out = EpisodeStore.create(path, meta, overwrite=True, robot_from=source.path)
    skip = {"episode_index", "start", "length", "duration_s", "crc32"}
    try:
        batch = []
        for index, data in source.iter_episodes():
            info = {k: v for k, v in source.episode_info(index).items() if k not in skip}
            info["dagger_round"] = 0
            info["labels"] = len(data["action"])
            batch.append(({**data, LABEL_KEY: np.ones(len(data["action"]), np.uint8)}, info))
        out.append_episodes(batch)
    except BaseException:
        out.abandon()  # no half-made aggregate (nor its staging folder) stays behind
        raise
    return out


def make_env_for_store(store: EpisodeStore, task: str | None, robot: str | None = None) -> Any:
    """The store's task with its robot (``robot``: a config that replaces the recorded one), rendering
    the store's cameras, so that a pixel policy's rollouts are stored like its demonstrations."""
    from demo.sim import make_env
    from demo.sim.robot_record import resolve_robot
    from demo.train.observation import camera_list, image_keys

    t = store.meta.task or {}
    name = t.get("name")
    if task and name and task != name:
        raise DemoError(store.path, f"holds {name!r} demonstrations; DAgger cannot aggregate {task!r} rollouts into it")
    task = task or name
    if not task:
        raise DemoError(store.path, "records no task; pass --task")
    features = store.meta.features
    cameras = camera_list((k, features[k].shape) for k in image_keys(features))
    env = make_env(task, robot=resolve_robot(store.meta.robot, robot, where=store.path), cameras=cameras,
                   **(t.get("options") or {}))
    if env.action_spec.name != store.meta.action.name or env.action_spec.dim != store.meta.action.dim:
        env.close()
        raise DemoError(
            store.path,
            f"DAgger needs expert labels in the store's action representation ({store.meta.action.name}); "
            f"the expert speaks {env.action_spec.name}",
        )
    return env


# ================================================================================== one round's rollouts
def dagger_episode(env: Any, actor: Any, seed: int, beta: float, gate: float | None, n_arm: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One rollout of the mixture (or gated) policy with every visited state labelled by the expert."""
    env.reset(seed)
    actor.reset(seed, env)
    expert = env.expert(rng=np.random.default_rng([seed, 2]))
    mix = np.random.default_rng([seed, 3])
    labelled: list[bool] = []
    in_control = [False]
    expert_steps = [0]

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        label = np.asarray(expert.act(env), dtype=np.float32)
        mine = np.asarray(actor.act(frame), dtype=np.float32)
        if gate is not None:
            # A gripper the learner leaves open where the expert closes it (or the reverse) is
            # straying too, though no arm joint deviates: the stall a supervisor steps in for.
            deviation = float(np.abs(mine[:n_arm] - label[:n_arm]).max())
            if mine.shape[0] > n_arm and abs(float(mine[n_arm] - label[n_arm])) > GRIPPER_GATE:
                deviation = max(deviation, 2.0 * gate)
            if in_control[0]:
                in_control[0] = deviation > gate / 2
            else:
                in_control[0] = deviation > gate
            use_expert = in_control[0]
            labelled.append(use_expert)
        else:
            use_expert = bool(mix.random() < beta) if beta > 0 else False
            labelled.append(True)
        expert_steps[0] += int(use_expert)
        executed = label if use_expert else mine
        return StepCommand(executed=executed, label=label, ee_target=np.asarray(expert.ee_target, np.float32))

    episode = rollout(env, seed, act, reset=False)
    data = dict(episode.data)
    data[LABEL_KEY] = np.asarray(labelled, dtype=np.uint8)
    info = {
        "success": episode.success,
        "seed": seed,
        "source": "dagger",
        "operator": "expert",
        "first_success_step": -1 if episode.first_success_step is None else episode.first_success_step,
        "labels": int(np.sum(labelled)),
        "expert_steps": expert_steps[0],
        "beta": float(beta),
    }
    return data, info


# ================================================================================== the run
def train_dagger(config: DaggerConfig, *, progress: Progress | None = None, resume: bool = False,
                 overwrite: bool = False, command: str | None = None) -> dict[str, Any]:
    """Round 0 (BC on the demonstrations), then ``rounds`` of expert-labelled rollouts + retraining."""
    tc = config.train = learner_config(**config.train.given())
    config.check()
    gate = config.gate_threshold()
    source_path = Path(tc.data)
    total_steps = tc.steps + config.rounds * config.round_steps
    run = TrainingRun(tc, progress=progress, resume=resume, overwrite=overwrite, command=command,
                      total_steps=total_steps, name="dagger", title=f"dagger ({tc.algo}) on {source_path.name}")

    # ---- 0. the environment and the aggregate store (in the run directory)
    agg_path = run.out / DATA_DIR
    with ExitStack() as stack:
        if resume:
            run.open_directory()  # a run without a train state is refused first
        # The environment comes from the data DAgger aggregates into: the source for a new run, so that
        # a wrong task or robot fails before anything is written; the run's own copy when resuming.
        with EpisodeStore.open(agg_path if resume else source_path) as origin:
            env = stack.enter_context(closing(make_env_for_store(origin, config.task, tc.robot)))
            run.open_directory()
            if not resume:
                store = create_aggregate(origin, agg_path)
        if resume:
            store = EpisodeStore.open(agg_path, "a")
        stack.enter_context(store)
        stack.enter_context(run)
        features = {k for k in store.meta.features if k != LABEL_KEY}
        recorded = {*env.frame().keys(), "action", "info.executed_action", "info.ee_target"}
        if features != recorded:
            raise DemoError(source_path, f"records {sorted(features)}; DAgger rollouts record {sorted(recorded)}")
        n_arm = len(env.robot.arm_joints)

        # ---- the demonstrations: round 0's data and normalisers (kept for every round unless refit)
        round0 = dataclasses.replace(tc, data=str(agg_path))
        demos = prepare(round0, store, among=np.flatnonzero(store.column("dagger_round") == 0))
        demo_val = demos.val_episodes
        demo_labels = demos.frames(np.union1d(demos.train_episodes, demo_val))

        def round_data(r: int) -> TrainingData:
            """Training data of the learner trained after round ``r``: demonstrations + rounds 1..r."""
            if r == 0:
                return demos
            rounds_col = store.column("dagger_round")
            episodes = np.union1d(demos.train_episodes, np.flatnonzero((rounds_col >= 1) & (rounds_col <= r)))
            if config.warm_start or not config.refit_normalizers:
                return demos.reload(store, episodes, demo_val)
            return prepare(round0, store, split=(episodes, demo_val))

        def new_learner(data: TrainingData, r: int, step: int) -> Learner:
            return run.new_learner(data, step, tc.steps if r == 0 else config.round_steps, seed=tc.seed + 1000 * r)

        def labels_so_far(r: int) -> int:
            rounds_col, labels = store.column("dagger_round"), store.column("labels")
            return demo_labels + int(labels[(rounds_col >= 1) & (rounds_col <= r)].sum())

        data = demos
        learner = new_learner(demos, 0, 0)
        run.begin(store, demos, learner, {"name": "dagger", **config.to_json(), "source_data": str(source_path.resolve())})
        run.metrics["rounds"] = []
        done_round = -1
        if resume:
            saved = run.saved_extra()
            if not saved.get("round_done", False):
                raise DemoError(run.out, "was interrupted inside a round; start it again without --resume")
            done_round = int(saved.get("round", 0))
            data = round_data(done_round)
            learner = new_learner(data, done_round, 0)
            run.attach(learner, data)
            run.restore(learner)

        # ---- round 0: behaviour cloning on the demonstrations
        if done_round < 0:
            run.fit(tc.steps)
            run.metrics["rounds"].append(_round_entry(0, 0.0, [], demo_labels, demo_labels, learner.step, run.evaluate()))
            run.checkpoint({"round": 0, "round_done": True})
        # ---- rounds 1..R: roll out, aggregate, retrain
        for r in range(max(done_round, 0) + 1, config.rounds + 1):
            beta = config.beta_at(r)
            existing = np.flatnonzero(store.column("dagger_round") == r)  # reused after an interruption
            infos = [store.episode_info(int(i)) for i in existing]
            actor = make_actor(run.bundle(), env, run.execution)
            with single_thread():
                for k, seed in enumerate(dagger_seeds(tc.seed, r, config.episodes_per_round)[len(existing):]):
                    run.tick(info=f"round {r}: rollout {len(existing) + k + 1}/{config.episodes_per_round}")
                    episode, info = dagger_episode(env, actor, seed, beta, gate, n_arm)
                    info.update(task=store.meta.task.get("name", ""), dagger_round=r)
                    store.append_episode(episode, **info)
                    infos.append(info)
            data = round_data(r)
            if config.warm_start:
                learner.phase_start, learner.phase_steps = learner.step, config.round_steps
                run.attach(learner, data)
            else:
                learner = new_learner(data, r, learner.step)
                run.attach(learner, data)
            run.fit(learner.step + config.round_steps)
            entry = run.evaluate()
            labels_round = int(sum(int(i["labels"]) for i in infos))
            last = _round_entry(r, beta, infos, labels_round, labels_so_far(r), learner.step, entry)
            run.metrics["rounds"].append(last)
            run.checkpoint({"round": r, "round_done": True})
            run.tick(message=f"round {r}: beta {beta:.2f}, rollout success {last['rollout_success']:.0%}, "
                             f"labels {last['labels_round']} (total {last['labels_total']})"
                             + (f", eval success {entry['success_rate']:.0%}" if entry else ""))

        total_labels = labels_so_far(config.rounds)
        run.record["data"]["expert_labels"] = total_labels
        run.record["data"]["seeds"] = [int(x) for x in store.column("seed") if int(x) >= 0]
        summary = run.finish({"round": config.rounds, "round_done": True}, demo_labels=demo_labels,
                             episodes=store.num_episodes)
    return {**summary, "algo": "dagger", "rounds": run.metrics["rounds"]}


def _round_entry(r: int, beta: float, infos: list[dict[str, Any]], labels_round: int, labels_total: int, step: int,
                 entry: dict[str, Any] | None) -> dict[str, Any]:
    return {
        "round": r,
        "beta": beta,
        "episodes": len(infos),
        "rollout_success": float(np.mean([bool(i["success"]) for i in infos])) if infos else None,
        "expert_steps": int(sum(int(i.get("expert_steps", 0)) for i in infos)),
        "labels_round": labels_round,
        "labels_total": labels_total,
        "step": step,
        "eval_success": entry["success_rate"] if entry else None,
    }
