"""DAgger (Ross, Gordon & Bagnell 2011) and HG-DAgger (Kelly et al. 2019) with the tasks' experts.

``demo train DATA --algo dagger --task T --rounds R --episodes-per-round K`` runs :func:`train_dagger`:

0. DATA's episodes are copied into the run's own store ``RUN/data.zarr`` (DATA is never modified),
   with a per-frame flag ``info.labelled``; round 0 trains behaviour cloning on them exactly as
   ``--algo bc`` would (:mod:`demo.train.bc`).
1. Round ``r = 1..R`` rolls out ``K`` episodes (seeds: :mod:`demo.train.seeds`) of the mixture
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
label budgets (``metrics.json`` ``rounds[*].labels_total``). DART-style data (``demo collect
--noise``: noise on the executed action, clean labels) trains with ``--algo bc`` and the same
label accounting.

``--resume`` continues at the round where a run stopped (a round's rollouts already in the store
are reused, not repeated).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from demo.collect.rollout import StepCommand, rollout
from demo.errors import DemoError
from demo.store import EpisodeStore, FeatureSpec, StoreMeta
from demo.train import bc
from demo.train import checkpoint as ckpt
from demo.train.evaluate import make_actor, single_thread
from demo.train.policy import build_policy, policy_config
from demo.train.progress import TrainProgress
from demo.train.seeds import dagger_seeds

DATA_DIR = "data.zarr"
GRIPPER_GATE = 0.5  # HG-DAgger: a gripper command this far (of 0 open .. 1 closed) from the expert's is a deviation


@dataclass
class DaggerConfig:
    """DAgger's own hyperparameters; ``train`` holds round 0's (and the optimiser's)."""

    train: bc.TrainConfig = field(default_factory=bc.TrainConfig)
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


# ================================================================================== the aggregate store
def create_aggregate(source: EpisodeStore, path: Path) -> EpisodeStore:
    """A copy of ``source`` with the per-frame ``info.labelled`` flag (all True for its episodes)."""
    meta = StoreMeta.from_json(source.meta.to_json())
    meta.features[bc.LABEL_KEY] = FeatureSpec((), "uint8", "1 where the action is an expert label", "")
    meta.provenance = [*meta.provenance, {"op": "dagger", "from": str(source.path), "time": ckpt.now()}]
    out = EpisodeStore.create(path, meta, overwrite=True)
    skip = {"episode_index", "start", "length", "duration_s", "crc32"}
    batch = []
    for index, data in source.iter_episodes():
        info = {k: v for k, v in source.episode_info(index).items() if k not in skip}
        info["dagger_round"] = 0
        info["labels"] = len(data["action"])
        batch.append(({**data, bc.LABEL_KEY: np.ones(len(data["action"]), np.uint8)}, info))
    out.append_episodes(batch)
    return out


def make_env_for_store(store: EpisodeStore, task: str | None) -> Any:
    from demo.sim import make_env

    t = store.meta.task or {}
    name = t.get("name")
    if task and name and task != name:
        raise DemoError(store.path, f"holds {name!r} demonstrations; DAgger cannot aggregate {task!r} rollouts into it")
    task = task or name
    if not task:
        raise DemoError(store.path, "records no task; pass --task")
    robot = (store.meta.robot or {}).get("config")
    env = make_env(task, robot=None if robot in (None, "builtin") else robot, **(t.get("options") or {}))
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
    data[bc.LABEL_KEY] = np.asarray(labelled, dtype=np.uint8)
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
def train_dagger(config: DaggerConfig, *, progress: bool = True, resume: bool = False, overwrite: bool = False,
                 command: str | None = None) -> dict[str, Any]:
    config.check()
    tc = config.train
    policy_config(tc.algo, tc.policy)
    out = Path(tc.out)
    if tc.threads > 0:
        torch.set_num_threads(tc.threads)
    torch.manual_seed(tc.seed)
    rng = np.random.default_rng([tc.seed, 0xB0C])
    gate = config.gate_threshold()
    source_path = Path(tc.data)

    # ---- 0. the aggregate store and the environment
    bc.prepare_run_dir(out, resume, overwrite)
    agg_path = out / DATA_DIR
    if resume:
        store = EpisodeStore.open(agg_path, "a")
    else:
        with EpisodeStore.open(source_path) as source:
            store = create_aggregate(source, agg_path)
    try:
        env = make_env_for_store(store, config.task)
    except DemoError:
        store.close()
        raise
    features = {k for k in store.meta.features if k != bc.LABEL_KEY}
    recorded = {*env.frame().keys(), "action", "info.executed_action", "info.ee_target"}
    if features != recorded:
        env.close()
        store.close()
        raise DemoError(source_path, f"records {sorted(features)}; DAgger rollouts record {sorted(recorded)}")
    n_arm = len(env.robot.arm_joints)

    # ---- round 0: behaviour cloning on the demonstrations (the data in the aggregate store)
    round0 = bc.TrainConfig(**{**asdict(tc), "data": str(agg_path)})
    demos = np.flatnonzero(store.column("dagger_round") == 0)
    s0 = bc.setup(round0, store, among=demos)
    demo_train, demo_val = s0.data.train_episodes, s0.data.val_episodes
    execution = bc.execution_config(tc, store.meta.action)
    demo_labels = s0.data.frames(np.union1d(demo_train, demo_val))

    def round_episodes(r: int) -> np.ndarray:
        rounds_col = store.column("dagger_round")
        return np.union1d(demo_train, np.flatnonzero((rounds_col >= 1) & (rounds_col <= r)))

    def round_setup(r: int) -> bc.Setup:
        """Data and normalisers of the learner trained after round ``r``."""
        if r == 0:
            return s0
        if config.warm_start or not config.refit_normalizers:
            data = bc.load_raw(store, s0.obs_spec, s0.relative).dataset(s0.obs_norm, s0.action_norm, round_episodes(r), demo_val)
            return bc.Setup(data, s0.obs_spec, s0.obs_norm, s0.action_norm, s0.relative, s0.spec)
        return bc.setup(round0, store, split=(round_episodes(r), demo_val))

    def new_learner(setup: bc.Setup, r: int, step: int) -> bc.Learner:
        torch.manual_seed(tc.seed + 1000 * r)
        fresh = bc.make_learner(build_policy(tc.algo, setup.spec, policy_config(tc.algo, tc.policy)), tc)
        fresh.step = fresh.phase_start = step
        fresh.phase_steps = tc.steps if r == 0 else config.round_steps
        return fresh

    s = s0
    learner = new_learner(s0, 0, 0)
    record = {"name": "dagger", **config.to_json(), "source_data": str(source_path.resolve())}
    run = bc.run_record(round0, store, s0, learner.policy, execution, command, record)
    metrics: dict[str, Any] = {"train_loss": [], "val_loss": [], "eval": [], "rounds": []}
    done_round, round_done = 0, False
    if resume:
        state = ckpt.load_train_state(out)
        extra = json.loads(state.get("extra", "{}"))
        done_round, round_done = int(extra.get("round", 0)), bool(extra.get("round_done", False))
        if not round_done:
            raise DemoError(out, "was interrupted inside a round; start it again without --resume")
        s = round_setup(done_round)
        learner = new_learner(s, done_round, 0)
        metrics = bc.restore(learner, state, rng, out)
        run["created"] = ckpt.read_run(out).get("created", run["created"])
    ckpt.write_run(out, run)

    monitor = bc.Monitor(tc.eval_episodes, tc.seed) if (tc.eval_every or tc.eval_final) else None
    title = f"dagger ({tc.algo}) on {source_path.name}"
    total_steps = tc.steps + config.rounds * config.round_steps
    start = time.perf_counter()

    def bundle() -> ckpt.PolicyBundle:
        return bc.bundle_of(learner, s, store.meta.action, execution, run, out)

    def checkpoint(r: int, finished: bool) -> None:
        bc.save(out, learner, s.obs_norm, s.action_norm, rng, metrics, {"round": r, "round_done": finished}, title)

    def evaluate_now() -> dict[str, Any] | None:
        if monitor is None:
            return None
        result = monitor(bundle())
        entry = {"step": learner.step, **{k: result[k] for k in ("success_rate", "ci95", "episodes", "mean_length")}}
        metrics["eval"].append(entry)
        bar.update(learner.step, success=f"{result['successes']}/{result['episodes']}")
        return entry

    def labels_so_far(r: int) -> int:
        rounds = store.column("dagger_round")
        lab = store.column("labels")
        return demo_labels + int(lab[(rounds >= 1) & (rounds <= r)].sum())

    try:
        with TrainProgress(total_steps, "train dagger", progress, learner.step) as bar:
            # ---- round 0
            if not (done_round > 0 or round_done):
                bc.fit(learner, bc.BatchSource(s0.data, demo_train, tc.n_obs, tc.chunk), tc.steps, rng, metrics,
                       _val(s0.data, demo_val, tc), bar, None)
                entry = evaluate_now()
                metrics["rounds"].append(_round_entry(0, 0.0, [], demo_labels, demo_labels, learner.step, entry))
                done_round, round_done = 0, True
                checkpoint(0, True)
            # ---- rounds 1..R
            for r in range(done_round + 1, config.rounds + 1):
                beta = config.beta_at(r)
                existing = np.flatnonzero(store.column("dagger_round") == r)
                infos = [store.episode_info(int(i)) for i in existing]
                if len(existing) < config.episodes_per_round:
                    actor = make_actor(bundle(), env, execution)
                    seeds = dagger_seeds(tc.seed, r, config.episodes_per_round)[len(existing):]
                    with single_thread():
                        for k, seed in enumerate(seeds):
                            bar.update(info=f"round {r}: rollout {len(existing) + k + 1}/{config.episodes_per_round}")
                            ep_data, info = dagger_episode(env, actor, seed, beta, gate, n_arm)
                            info.update(task=store.meta.task.get("name", ""), dagger_round=r)
                            store.append_episode(ep_data, **info)
                            infos.append(info)
                # ---- train on the aggregate
                s = round_setup(r)
                if config.warm_start:
                    learner.phase_start, learner.phase_steps = learner.step, config.round_steps
                else:
                    learner = new_learner(s, r, learner.step)
                train_eps = s.data.train_episodes
                bc.fit(learner, bc.BatchSource(s.data, train_eps, tc.n_obs, tc.chunk), learner.step + config.round_steps,
                       rng, metrics, _val(s.data, demo_val, tc), bar, None)
                entry = evaluate_now()
                labels_round = int(sum(int(i["labels"]) for i in infos))
                metrics["rounds"].append(_round_entry(r, beta, infos, labels_round, labels_so_far(r), learner.step, entry))
                checkpoint(r, True)
                if progress:
                    last = metrics["rounds"][-1]
                    bar.log(f"round {r}: beta {beta:.2f}, rollout success {last['rollout_success']:.0%}, "
                            f"labels {last['labels_round']} (total {last['labels_total']})"
                            + (f", eval success {entry['success_rate']:.0%}" if entry else ""))
    finally:
        if monitor:
            monitor.close()
        env.close()
    total_labels = labels_so_far(config.rounds)
    n_episodes = store.num_episodes
    all_seeds = [int(x) for x in store.column("seed") if int(x) >= 0]
    store.close()
    metrics["final"] = {
        "step": learner.step,
        "train_loss": metrics["train_loss"][-1][1] if metrics["train_loss"] else None,
        "val_loss": metrics["val_loss"][-1][1] if metrics["val_loss"] else None,
        "success_rate": metrics["eval"][-1]["success_rate"] if metrics["eval"] else None,
        "seconds": time.perf_counter() - start,
        "expert_labels": total_labels,
        "demo_labels": demo_labels,
        "episodes": n_episodes,
    }
    run["data"]["expert_labels"] = total_labels
    run["data"]["seeds"] = all_seeds
    ckpt.write_run(out, run)
    bc.save(out, learner, s.obs_norm, s.action_norm, rng, metrics, {"round": config.rounds, "round_done": True}, title)
    return {"out": str(out), "algo": "dagger", **metrics["final"], "rounds": metrics["rounds"]}


def _val(data: bc.Dataset, val_eps: np.ndarray, tc: bc.TrainConfig) -> Any:
    return bc.BatchSource(data, val_eps, tc.n_obs, tc.chunk).fixed(4096, tc.seed)


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
