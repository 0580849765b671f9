"""DAgger (Ross, Gordon & Bagnell 2011) and HG-DAgger (Kelly et al. 2019) with the tasks' or foreign experts.

``demo train DATA --algo dagger --task T --rounds R --episodes-per-round K`` runs :func:`train_dagger`
(one file of ~500 lines on purpose: the loop every family member shares reads top to bottom, the
members' hooks in :class:`Family`, their configuration in :mod:`demo.imitation.config`):

0. DATA's episodes are copied into the run's own store ``RUN/data.zarr`` (DATA is never modified),
   with a per-frame flag ``info.labelled``; round 0 trains behaviour cloning on them exactly as
   ``--algo bc`` would (the shared :class:`demo.training.trainer.TrainingRun`).
1. Round ``r = 1..R`` rolls out ``K`` episodes (seeds: :mod:`demo.seeds`) of the mixture
   policy: at every step the expert is asked for its action on the visited state (the task experts
   are state-feedback policies, so any state can be labelled; a chunked learner's labels are chunks,
   below), and the executed action is the expert's with probability ``beta_r``, else the learner's.
   ``--beta``:

   - ``indicator``: ``beta_r = 0`` (round 0 already was the expert's data; Ross et al.'s choice);
   - ``linear:N``: ``beta_r = max(0, 1 - r / N)``;
   - ``exp:P``: ``beta_r = P ** r``.

   With ``--gate deviation:THRESH`` (HG-DAgger) the learner drives; the expert takes over when the
   learner's arm joint targets differ from its own by more than THRESH rad (max over joints), or
   its gripper command by more than :data:`GRIPPER_GATE`, and hands back once they agree within
   THRESH/2 (hysteresis, as a person would); only the frames it was in control of become labels.
   The rollouts run in this process, or with ``--workers N`` / ``--executor ray`` on workers
   (:mod:`demo.executor`) that get the learner's weights in memory; each is a function of its seed
   and the learner, so the episodes are the same wherever they ran.
2. The episodes are appended to ``RUN/data.zarr`` (source ``dagger``, columns ``dagger_round``,
   ``labels``, ``takeovers``), each visited state labelled by the expert (``action``), the executed
   action in ``info.executed_action``, and per frame ``info.intervention``: 1 where the expert, not
   the learner, was in control (HG-DAgger's takeovers, the beta draws that chose the expert; every
   frame of a demonstration).
3. A new learner is trained for ``round_steps`` on the aggregate (Ross et al.'s "train on D") with
   round 0's normalisers, fitted on the demonstrations: an early learner's rollouts flail (joints to
   their limits, the EE half a metre up), and min-max ranges refitted to them leave the states that
   matter a fraction of the input range (on ``stack``, the joint ranges were 4x wider after the
   rounds; inputs outside the demonstrations' ranges are clipped, see
   :data:`demo.policies.normalizer.OBS_CLIP`).
   ``refit_normalizers`` refits them to the aggregate's labelled frames instead (the default with
   segment labels, below, whose labelled frames are the expert's own states); ``warm_start`` fine-tunes
   the previous learner instead of training a new one (cheaper).

Expert labels are counted: every frame of DATA's episodes that training used (validation
included) plus every labelled frame of every round, so comparisons with BC can be made at equal
label budgets (``metrics.json`` ``rounds[*].labels_total``); ``max_labels`` stops the rollouts once the
count reaches it (at the end of the episode that reaches it). DART-style data (collected with
``--noise``: noise on the executed action, clean labels) trains with ``--algo bc`` and the same
label accounting.

``--resume`` continues at the round where a run stopped (a round's rollouts already in the store
are reused, not repeated).

The family: SafeDAgger (:mod:`demo.imitation.safedagger`), AggreVaTe (:mod:`demo.imitation.aggrevate`), DART
(:mod:`demo.imitation.dart`) and state perturbation (:mod:`demo.imitation.perturb`) run this same loop with
their own rounds: a :class:`Family` says what round ``r`` rolls out (an episode function, run here or on
the workers) and what its metrics add (:func:`make_family`; ``demo train --algo NAME``).

On a foreign environment (``demo collect --env ENV --expert EXPERT`` data: gym-aloha, Meta-World) the
expert that collected the data is asked from the environment's observation (:func:`recorded_expert`,
:class:`demo.collect.foreign.ForeignExpert`); its state cannot be saved, so the labels are single
actions (:func:`foreign_family`), and the gate reads grippers by their action names (:class:`ActionParts`).

The learner is BC's policy with BC's defaults, 16-step chunks executed with temporal ensembling
(``--learner``: another policy, e.g. ACT, with its own defaults). A chunked learner is trained on *chunk
labels* (:class:`ChunkLabels`, ``chunk_labels``; on for DAgger, off under a gate): at a labelled state
the expert's own next ``chunk`` actions, looked ahead in the simulator from that state and executing its
own actions (:func:`expert_chunk`), at most one every ``label_stride`` steps (default: the chunk) and
each of its actions counted as a label, so a rollout step costs one label as before. The single-step
labels at the states a learner visits next are answers in states the expert would not have reached, and
a window of them is not the plan a chunked learner is trained to predict (pick from 10 demos, 5 rounds x
10 rollouts: 5/100 with such windows, 46/100 with chunk labels). Under HG-DAgger's gate the labels are
the expert's own consecutive actions while it is in control, which already are its plan: dense
single-step labels there (96/100 at 2,322 labels; chunk labels every 16 steps: 87/100). By default the
look-ahead is kept whole, its states included (*segment labels*, ``segment_labels``; :func:`expert_segment`):
a short demonstration from the visited state, stored as an episode of its own beside the rollout (source
:data:`SEGMENT_SOURCE`, its labels counted on the rollout), so the same labels train a window at each of its
states, not one (pick, the same settings: 69/100 with chunk labels, 80/100 with segments, 94/100 with the
normalisers refit to them). Everything else
of a run (seeding, the run directory, the loop, checkpoints, metrics) is the shared
:class:`demo.training.trainer.TrainingRun`'s; this file holds only what is DAgger's own.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import ExitStack, closing
import copy
import dataclasses
from dataclasses import dataclass
import importlib
from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np
import torch

from demo.collect.foreign import ForeignExpert
from demo.errors import DemoError
from demo.evaluation.evaluate import make_actor, single_thread
from demo.executor import ExecutorConfig, ordered_map, session
from demo.imitation.config import FAMILY, DaggerConfig, learner_config
from demo.policies import checkpoint as ckpt
from demo.policies.actor import ExecConfig
from demo.policies.observation import camera_list, image_keys
from demo.progress import Progress
from demo.seeds import dagger_seeds
from demo.sim import make_env
from demo.sim.foreign import is_foreign
from demo.sim.foreign_set import set_members
from demo.sim.robot_record import resolve_robot
from demo.sim.rollout import StepCommand, rollout
from demo.store import EpisodeStore, FeatureSpec, StoreMeta
from demo.store.location import absolute, store_path
from demo.training.data import CHUNK_KEY, HAS_CHUNK_KEY, LABEL_KEY, TrainingData, prepare
from demo.training.optim import Learner
from demo.training.trainer import TrainingRun

DATA_DIR = "data.zarr"
GRIPPER_GATE = 0.5  # HG-DAgger: a gripper command this far (of 0 open .. 1 closed) from the expert's is a deviation
INTERVENTION_KEY = "info.intervention"  # per frame: 1 where the expert, not the learner, was in control
SEGMENT_SOURCE = "dagger-segment"  # the source of an expert look-ahead stored as its own episode (ChunkLabels.segments)


# ================================================================================== the aggregate store
def create_aggregate(source: EpisodeStore, path: Path, chunk: int = 1) -> EpisodeStore:
    """A copy of ``source`` with the per-frame ``info.labelled`` flag (all True for its episodes) and, for a
    chunked learner (``chunk`` > 1), room for chunk labels (:data:`CHUNK_KEY`; a demonstration's frames
    have none: the actions it went on to execute are the expert's chunk)."""
    meta = StoreMeta.from_json(source.meta.to_json())
    meta.features[LABEL_KEY] = FeatureSpec((), "uint8", "1 where the action is an expert label", "")
    meta.features[INTERVENTION_KEY] = FeatureSpec((), "uint8", "1 where the expert, not the learner, was in control", "")
    dim = source.meta.action.dim
    if chunk > 1:
        meta.features[CHUNK_KEY] = FeatureSpec((chunk, dim), "float32", "the expert's action chunk from this state "
                                               "(looked ahead in the simulator) where info.has_label_chunk", "")
        meta.features[HAS_CHUNK_KEY] = FeatureSpec((), "uint8", "1 where info.label_chunk holds a chunk label", "")
    meta.provenance = [*meta.provenance, {"op": "dagger", "from": str(source.path), "time": ckpt.now()}]
    out = EpisodeStore.create(path, meta, overwrite=True, robot_from=source.path)
    skip = {"episode_index", "start", "length", "duration_s", "crc32"}
    try:
        batch = []
        for index, data in source.iter_episodes():
            info = {k: v for k, v in source.episode_info(index).items() if k not in skip}
            info["dagger_round"] = 0
            info["labels"] = len(data["action"])
            ones = np.ones(len(data["action"]), np.uint8)  # a demonstration: expert labels, the expert in control
            flags = {LABEL_KEY: ones, INTERVENTION_KEY: ones}
            if chunk > 1:
                flags[CHUNK_KEY] = np.zeros((len(ones), chunk, dim), np.float32)
                flags[HAS_CHUNK_KEY] = np.zeros(len(ones), np.uint8)
            batch.append(({**data, **flags}, info))
        out.append_episodes(batch)
    except BaseException:
        out.abandon()  # no half-made aggregate (nor its staging folder) stays behind
        raise
    return out


def rollout_env_args(store: EpisodeStore, task: str | None, robot: str | None = None) -> tuple[str, dict[str, Any]]:
    """``make_env``'s task and keyword arguments for rollouts aggregated into ``store``: its task with
    its robot (``robot``: a config that replaces the recorded one, resolved here), rendering the
    store's cameras, so that a pixel policy's rollouts are stored like its demonstrations."""
    t = store.meta.task or {}
    name = t.get("name")
    if task and name and task != name:
        raise DemoError(store.path, f"holds {name!r} demonstrations; DAgger cannot aggregate {task!r} rollouts into it")
    task = task or name
    if not task:
        raise DemoError(store.path, "records no task; pass --task")
    if is_foreign(task):  # it brings its own robot and cameras; its options rebuild it as it was
        if robot is not None:
            raise DemoError("--robot", "a Gymnasium environment brings its own robot")
        return task, dict(t.get("options") or {})
    features = store.meta.features
    cameras = camera_list((k, features[k].shape) for k in image_keys(features))
    return task, {"robot": resolve_robot(store.meta.robot, robot, where=store.path), "cameras": cameras,
                  **(t.get("options") or {})}


def recorded_expert(store: EpisodeStore) -> str:
    """The expert that collected a foreign environment's demonstrations (``demo collect --expert``, as the
    store's provenance records it): the one DAgger asks in the states its learner visits."""
    names = {p.get("expert") for p in store.meta.provenance if p.get("op") == "collect" and p.get("expert")}
    if len(names) != 1:
        found = "no expert" if not names else f"several experts ({', '.join(sorted(names))})"
        raise DemoError(store.path, f"records {found}; DAgger on a foreign environment asks the one expert "
                                    "that collected the data (demo collect --env ENV --expert EXPERT)")
    return names.pop()


def make_env_for_store(store: EpisodeStore, task: str, env_kwargs: dict[str, Any]) -> Any:
    """The rollout environment (:func:`rollout_env_args`); refuses an expert that does not label in the
    store's action representation."""
    env = make_env(task, **env_kwargs)
    if env.action_spec.name != store.meta.action.name or env.action_spec.dim != store.meta.action.dim:
        env.close()
        raise DemoError(
            store.path,
            f"DAgger needs expert labels in the store's action representation ({store.meta.action.name}); "
            f"the expert speaks {env.action_spec.name}",
        )
    return env


# ================================================================================== one round's rollouts
@dataclass(frozen=True)
class ActionParts:
    """Which dimensions of an action HG-DAgger's gate compares, and how: ``targets`` (joint position
    targets, rad on an arm; a foreign environment's continuous commands in their own units) by their
    largest difference, ``grippers`` (commands from 0 to 1) by whether they differ by more than
    :data:`GRIPPER_GATE`."""

    targets: tuple[int, ...]
    grippers: tuple[int, ...] = ()

    @classmethod
    def of(cls, env: Any) -> "ActionParts":
        """A task's arm joints and its gripper; a foreign environment's action by name: a dimension whose
        name holds ``gripper`` (gym-aloha's ``left.gripper``, ``right.gripper``) is a gripper, the rest targets."""
        dim = env.action_spec.dim
        if env.robot is not None:
            n_arm = len(env.robot.arm_joints)
            return cls(tuple(range(n_arm)), tuple(range(n_arm, min(dim, n_arm + 1))))
        grippers = tuple(i for i, name in enumerate(env.action_spec.names) if "gripper" in name.lower())
        return cls(tuple(i for i in range(dim) if i not in grippers), grippers)


def deviation(mine: np.ndarray, label: np.ndarray, parts: ActionParts, gate: float) -> np.ndarray:
    """How far the learner's actions stray from the expert's (``[..., A]`` each -> ``[...]``; rad on an
    arm): the largest target difference, raised to ``2 gate`` where a gripper command differs by more
    than :data:`GRIPPER_GATE`. A gripper the learner leaves open where the expert closes it (or the
    reverse) is straying too, though no arm joint deviates: the stall a supervisor steps in for."""
    mine, label = np.asarray(mine, np.float32), np.asarray(label, np.float32)
    targets, grippers = list(parts.targets), list(parts.grippers)
    d = np.abs(mine[..., targets] - label[..., targets]).max(axis=-1)
    if grippers:
        wrong = (np.abs(mine[..., grippers] - label[..., grippers]) > GRIPPER_GATE).any(axis=-1)
        d = np.where(wrong, np.maximum(d, 2.0 * gate), d)
    return d


# A gate decides, each step, whether the expert takes over: gate(frame, learner's action, expert's action).
Gate = Callable[[dict[str, np.ndarray], np.ndarray, np.ndarray], bool]


class DeviationGate:
    """HG-DAgger's supervisor for one episode: takes over when :func:`deviation` exceeds ``threshold``
    (rad) and hands back once it is below half of it (hysteresis, as a person would)."""

    def __init__(self, threshold: float, parts: ActionParts):
        self.threshold, self.parts, self.in_control = threshold, parts, False

    def __call__(self, frame: dict[str, np.ndarray], mine: np.ndarray, label: np.ndarray) -> bool:
        d = float(deviation(mine, label, self.parts, self.threshold))
        self.in_control = d > (self.threshold / 2 if self.in_control else self.threshold)
        return self.in_control


@dataclass(frozen=True)
class ChunkLabels:
    """DAgger's labels for a chunked learner. A single action is the expert's answer in one state, and
    the actions at the states a learner visits next are answers in states the expert would not have
    reached, not a plan: a window of them is not what a chunked learner is trained to predict. So a
    labelled state gets the expert's own chunk from there (:func:`expert_chunk`): ``horizon`` actions,
    each counted as a label, at most one such label every ``stride`` steps of a rollout (``stride`` =
    ``horizon`` spends as many labels per rollout step as single-step labels on every step).

    ``segments``: the look-ahead is kept whole, states included (:func:`expert_segment`): a short
    demonstration from the visited state, stored as an episode of its own, so its ``horizon`` labels
    train a window at each of its ``horizon`` states (the later ones on the rest of the segment, the
    steps past its end padding) instead of one window at the visited state."""

    horizon: int
    stride: int
    segments: bool = False


def expert_chunk(env: Any, expert: Any, first: np.ndarray, horizon: int) -> np.ndarray:
    """``[horizon, A]`` (float32): ``first``, the expert's action in ``env``'s current state, then the
    actions a copy of the expert takes in the states its own actions lead to, looked ahead in ``env``
    without observing (:meth:`demo.sim.env.Env.advance`). ``env``'s state is restored after, so the
    rollout goes on exactly as it would have (:meth:`demo.sim.env.Env.snapshot`: MuJoCo's integration
    state and any commands a randomised latency holds back)."""
    out = np.empty((horizon, len(first)), np.float32)
    out[0] = first
    if horizon > 1:
        snapshot = env.snapshot()
        ahead = copy.deepcopy(expert)  # the rollout's expert keeps its own state (its rng, its last target)
        try:
            env.advance(first)
            for k in range(1, horizon):
                out[k] = ahead.act(env)
                if k + 1 < horizon:
                    env.advance(out[k])
        finally:
            env.restore(snapshot)
    return out


def expert_segment(env: Any, expert: Any, first: np.ndarray, target: np.ndarray | None, seed: int,
                   horizon: int) -> Any:
    """The expert's own next ``horizon`` steps from ``env``'s current state, recorded as collection records
    an episode (:func:`demo.sim.rollout.rollout`): ``first`` (its action here, with its end-effector
    ``target``), then a copy of the expert acting in the states its own actions lead to. ``env``'s state is
    restored after (:meth:`demo.sim.env.Env.snapshot`), so the learner's rollout goes on exactly as it would
    have; the segment is what the expert would have shown from the learner's state (:class:`ChunkLabels`)."""
    snapshot = env.snapshot()
    ahead = copy.deepcopy(expert)  # the rollout's expert keeps its own state (its rng, its last target)

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        if t == 0:
            return StepCommand(executed=first, label=first, ee_target=target)
        action = np.asarray(ahead.act(env), dtype=np.float32)
        known = None if ahead.ee_target is None else np.asarray(ahead.ee_target, np.float32)
        return StepCommand(executed=action, label=action, ee_target=known)

    try:
        return rollout(env, seed, act, max_steps=horizon, hold_success_s=None, reset=False)
    finally:
        env.restore(snapshot)


def dagger_episode(env: Any, actor: Any, seed: int, beta: float, gate: float | Gate | None, parts: ActionParts,
                   chunks: ChunkLabels | None = None, expert: str | None = None
                   ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One rollout of the mixture policy (``beta``), or of the learner under ``gate`` (a threshold:
    HG-DAgger's :class:`DeviationGate`; or any :data:`Gate`, e.g. SafeDAgger's classifier), every
    visited state labelled by the expert; under a gate only the frames the expert took are labels.
    ``chunks``: labels are the expert's chunks, at most one every ``chunks.stride`` steps (:class:`ChunkLabels`).
    ``expert``: a foreign environment's expert by name (:class:`demo.collect.foreign.ForeignExpert`; a
    task's own expert otherwise)."""
    env.reset(seed)
    actor.reset(seed, env)
    teacher = ForeignExpert(expert, env) if expert else env.expert(rng=np.random.default_rng([seed, 2]))
    mix = np.random.default_rng([seed, 3])
    decide = DeviationGate(gate, parts) if isinstance(gate, (int, float)) else gate
    labelled: list[bool] = []
    in_control: list[bool] = []
    chunk_labels: list[np.ndarray] = []
    segments: list[Any] = []  # chunks.segments: the expert's recorded look-aheads (demo.sim.rollout.Episode)
    since_chunk = [chunks.stride if chunks else 0]  # steps since the last chunk label

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        label = np.asarray(teacher.act(env), dtype=np.float32)
        mine = np.asarray(actor.act(frame), dtype=np.float32)
        if decide is not None:
            use_expert = bool(decide(frame, mine, label))
            is_label = use_expert
        else:
            use_expert = bool(mix.random() < beta) if beta > 0 else False
            is_label = True
        target = None if teacher.ee_target is None else np.asarray(teacher.ee_target, np.float32)
        if chunks is not None:
            is_label = is_label and since_chunk[0] >= chunks.stride
            since_chunk[0] = 1 if is_label else since_chunk[0] + 1
            if is_label and chunks.segments:  # the label lives in the segment's episode, not on this frame
                segments.append(expert_segment(env, teacher, label, target, seed, chunks.horizon))
                is_label = False
            chunk_labels.append(expert_chunk(env, teacher, label, chunks.horizon) if is_label
                                else np.full((chunks.horizon, len(label)), np.nan, np.float32))
        labelled.append(is_label)
        in_control.append(use_expert)
        executed = label if use_expert else mine
        return StepCommand(executed=executed, label=label, ee_target=target)

    episode = rollout(env, seed, act, reset=False)
    stacked = np.stack(chunk_labels) if chunks else None
    data, info = episode_record(episode, seed, labelled, in_control, beta, chunks=stacked)
    if segments:
        info["segments"] = [segment_record(s, seed, beta, stacked.shape[1:]) for s in segments]
        info["labels"] += sum(s.length for s in segments)  # counted on the rollout that asked for them
    return data, info


def segment_record(segment: Any, seed: int, beta: float, chunk_shape: tuple[int, ...]
                   ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """An :func:`expert_segment` as the aggregate stores it: an episode of expert labels, the expert in
    control throughout, without chunk labels (its windows' chunks are its own next actions) and with
    ``labels`` 0 in its row (its labels are counted on the rollout it came from, whose ``labels`` they are)."""
    ones = np.ones(segment.length, bool)
    data, info = episode_record(segment, seed, ones, ones, beta, source=SEGMENT_SOURCE,
                                chunks=np.full((segment.length, *chunk_shape), np.nan, np.float32))
    return data, {**info, "labels": 0, "takeovers": 0}


def episode_record(episode: Any, seed: int, labelled: Sequence[bool], in_control: Sequence[bool], beta: float,
                   source: str = "dagger", chunks: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """A family rollout (a recorded :class:`demo.sim.rollout.Episode`) as the aggregate stores it: its
    frames with the per-frame flags ``info.labelled`` and ``info.intervention`` (and ``chunks``, ``[T, H, A]``
    chunk labels, NaN on frames without, as :data:`CHUNK_KEY` and :data:`HAS_CHUNK_KEY`), and its table row (``labels``, every labelled
    action: a chunk label counts its length; ``expert_steps``, the frames the expert was in control of;
    ``takeovers``, how often it took over from the learner)."""
    data = dict(episode.data)
    data[LABEL_KEY] = np.asarray(labelled, dtype=np.uint8)
    flags = np.asarray(in_control, dtype=np.uint8)
    data[INTERVENTION_KEY] = flags
    labels = int(np.sum(data[LABEL_KEY]))
    if chunks is not None:
        has = np.isfinite(chunks[:, 0, 0])
        data[CHUNK_KEY] = np.where(has[:, None, None], chunks, 0.0).astype(np.float32)
        data[HAS_CHUNK_KEY] = has.astype(np.uint8)
        labels *= chunks.shape[1]
    info = {
        "success": episode.success,
        "seed": seed,
        "source": source,
        "operator": "expert",
        "first_success_step": -1 if episode.first_success_step is None else episode.first_success_step,
        "labels": labels,
        "expert_steps": int(flags.sum()),
        "takeovers": int((np.diff(np.r_[0, flags.astype(np.int64)]) == 1).sum()),
        "beta": float(beta),
    }
    return data, info


# An episode function: (env, actor, seed) -> (frames, table row) of one rollout. Picklable: workers run it.
EpisodeFn = Callable[[Any, Any, int], tuple[dict[str, np.ndarray], dict[str, Any]]]


@dataclass(frozen=True)
class MixtureEpisodes:
    """DAgger's and HG-DAgger's rollouts (:func:`dagger_episode`) as an :data:`EpisodeFn`."""

    beta: float
    gate: Any  # float | Gate | None
    parts: ActionParts
    chunks: ChunkLabels | None = None
    expert: str | None = None  # a foreign environment's expert (module:callable); None: the task's

    def __call__(self, env: Any, actor: Any, seed: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        return dagger_episode(env, actor, seed, self.beta, self.gate, self.parts, self.chunks, self.expert)


@dataclass
class Family:
    """What a member of the DAgger family does in its rounds; this base class is DAgger (and, with a
    gate, HG-DAgger) itself. Subclasses (SafeDAgger, AggreVaTe, DART, perturbation) override
    :meth:`episodes` and may add per-round metrics (:meth:`round_entry`) and recorded settings."""

    name: str = "dagger"
    chunk_labels: ChunkLabels | None = None  # set by train_dagger for a chunked learner (CHUNK_LABELS members)
    expert: str | None = None  # set by train_dagger on a foreign environment: the expert that collected the data
    OPTIONS: ClassVar[tuple[str, ...]] = ()  # the fields ``--algo-opt KEY=VALUE`` may set
    CHUNK_LABELS: ClassVar[bool] = True  # whether its rollouts label states with expert chunks (ChunkLabels)
    # Whether it runs on a foreign environment, whose expert answers from the observation and whose state cannot
    # be saved and restored: DAgger and HG-DAgger with single-step labels do; the members that need the
    # simulator's state or the task's own expert (its noise, its cost-to-go) do not.
    FOREIGN: ClassVar[bool] = True

    def episodes(self, run: TrainingRun, store: EpisodeStore, env: Any, r: int, beta: float,
                 gate: float | None) -> EpisodeFn:
        """Round ``r``'s episode function, made when the attached learner is the one that rolls out
        (trained on the data through round ``r - 1``, ``run.data``)."""
        return MixtureEpisodes(beta, gate, ActionParts.of(env), self.chunk_labels, self.expert)

    def round_entry(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        """What the member adds to round ``r``'s metrics, from its episodes' table rows."""
        return {}

    def to_json(self) -> dict[str, Any]:
        """The member's own settings, recorded in ``run.json``."""
        return {}


def make_family(name: str, options: dict[str, str] | None = None) -> Family:
    """The family member ``name`` (:data:`demo.imitation.config.FAMILY`) with ``options`` (``--algo-opt
    KEY=VALUE``: text parsed to the type of the field's default; ``none`` for None)."""
    if name not in FAMILY:
        raise DemoError("--algo", f"unknown member of the DAgger family {name!r} (choose from {', '.join(FAMILY)})")
    module, _, cls_name = FAMILY[name].plugin.partition(":")
    # The members' modules import this one: looked up by name, not imported at the top.
    cls = getattr(importlib.import_module(module), cls_name)
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    for key, text in (options or {}).items():
        if key not in cls.OPTIONS:
            raise DemoError("--algo-opt", f"{name} has no option {key!r} (it has: {', '.join(cls.OPTIONS) or 'none'})")
        default = defaults[key]
        try:
            if text.lower() == "none":
                values[key] = None
            elif isinstance(default, tuple):
                values[key] = tuple(int(x) for x in text.split(","))
            else:
                values[key] = type(default)(text) if default is not None else float(text)
        except ValueError:
            raise DemoError("--algo-opt", f"{key}={text!r} is not a valid {type(default).__name__}") from None
    return cls(**values)


def learner_actions(bundle: ckpt.PolicyBundle, data: TrainingData, frames: np.ndarray, batch: int = 4096) -> np.ndarray:
    """The learner's action ``[N, A]`` at each of ``frames`` (indices into ``data``'s frames) as a
    rollout executes a single-step learner there: the first step of the chunk it predicts from the
    frame's observation history, made absolute (relative actions), binary dimensions thresholded.
    The family's estimates of the learner's error (SafeDAgger's deviation labels, DART's noise) use it."""
    windows = data.windows(np.zeros(0, np.int64))  # get() takes any frame indices
    device = next(bundle.policy.parameters()).device
    binary = list(bundle.execution.binary)
    out = [np.zeros((0, data.action.shape[1]), np.float32)]
    for i in range(0, len(frames), batch):
        t = np.asarray(frames[i : i + batch], dtype=np.int64)
        obs = windows.get(t)[0]
        obs = {k: v.to(device) for k, v in obs.items()} if isinstance(obs, dict) else obs.to(device)
        with torch.inference_mode():
            chunk = bundle.policy.predict(obs)
        a = bundle.action_norm.unnormalize(chunk[:, 0].float().cpu().numpy())
        if data.base is not None:
            a = a + data.base[t]
        if binary:
            a[:, binary] = (a[:, binary] >= 0.5).astype(a.dtype)
        out.append(a.astype(np.float32))
    return np.concatenate(out)


def round_rollouts(run: TrainingRun, env: Any, env_args: tuple[str, dict[str, Any]], seeds: Sequence[int],
                   episodes: EpisodeFn, executor: ExecutorConfig) -> Iterator[tuple[dict[str, np.ndarray], dict[str, Any]]]:
    """One round's ``episodes(env, actor, seed)`` of the attached learner, in seed order: in this process
    (``process`` executor with at most 1 worker), else on the executor's workers, which get the
    learner's weights in memory (never through a file) and run it on the learner's device (Ray
    actors reserve a share of the GPUs for a learner on CUDA). The episodes do not depend on where
    they ran."""
    bundle = run.bundle()
    if executor.kind == "process" and executor.workers <= 1:
        actor = make_actor(bundle, env, run.execution)
        with single_thread():
            for seed in seeds:
                yield episodes(env, actor, int(seed))
        return
    weights = ckpt.policy_tensors(bundle.policy.state_dict(), bundle.obs_norm, bundle.action_norm)
    init_args = (env_args, {"policy": bundle.run["policy"]}, {k: v.numpy() for k, v in weights.items()},
                 run.execution.to_json(), str(run.device))
    jobs = [(int(seed), episodes) for seed in seeds]
    for ready in ordered_map(_rollout_init, init_args, _rollout_run, jobs, executor.on_device(run.device),
                             label=lambda job: f"DAgger rollout (seed {job[0]})"):
        yield from ready


_rollout: dict[str, Any] = {}  # a worker's environment and learner


def _rollout_init(env_args: tuple[str, dict[str, Any]], record: dict[str, Any], weights: dict[str, np.ndarray],
                  execution: dict[str, Any], device: str) -> None:
    torch.set_num_threads(1)
    task, env_kwargs = env_args
    env = make_env(task, **env_kwargs)
    bundle = ckpt.bundle_from_tensors(record, {k: torch.tensor(v) for k, v in weights.items()}, device)
    _rollout["env"], _rollout["actor"] = env, make_actor(bundle, env, ExecConfig.from_json(execution))


def _rollout_run(job: tuple[int, EpisodeFn]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    seed, episodes = job
    return episodes(_rollout["env"], _rollout["actor"], seed)


# ================================================================================== the run
def foreign_family(family: Family, config: DaggerConfig, store: EpisodeStore, task: str) -> Family:
    """``family`` set to ask the expert that collected ``store`` (a foreign environment's, ``task``), or a
    one-line refusal: a task set, a member that needs the simulator's state, or chunk labels (looked ahead
    from a saved state)."""
    if set_members(task):
        raise DemoError(store.path, "holds a task set (one environment per episode); DAgger rolls out in one "
                                    "environment: collect one task per store")
    if not family.FOREIGN:
        raise DemoError("--algo", f"{family.name} needs a task's simulator and expert; on a foreign environment "
                                  "run dagger (with --gate deviation:THRESH for HG-DAgger)")
    if config.uses_chunk_labels() and config.train.chunk > 1:
        raise DemoError("--chunk-labels", "a foreign environment's state cannot be saved and looked ahead from, so "
                                          "its labels are single actions: give --gate deviation:THRESH (HG-DAgger) "
                                          "or --no-chunk-labels")
    return dataclasses.replace(family, expert=recorded_expert(store))


def train_dagger(config: DaggerConfig, *, executor: ExecutorConfig | None = None, progress: Progress | None = None,
                 resume: bool = False, overwrite: bool = False, command: str | None = None,
                 family: Family | None = None) -> dict[str, Any]:
    """Round 0 (BC on the demonstrations), then ``rounds`` of expert-labelled rollouts + retraining.

    ``executor``: where the rollouts run (default: in this process; see :func:`round_rollouts`);
    ``family``: the member whose rounds these are (default: DAgger, HG-DAgger with a gate)."""
    family = family or Family()
    config.check_learner()
    tc = config.train = learner_config(**{**config.train.given(), "algo": config.learner})
    config.check()
    executor = executor or ExecutorConfig("process", 1)
    executor.check()
    gate = config.gate_threshold()
    source_path = store_path(tc.data)
    total_steps = tc.steps + config.rounds * config.round_steps
    run = TrainingRun(tc, progress=progress, resume=resume, overwrite=overwrite, command=command,
                      total_steps=total_steps, name=family.name, title=f"{family.name} ({tc.algo}) on {source_path.name}")

    # ---- 0. the environment and the aggregate store (in the run directory)
    agg_path = run.out / DATA_DIR
    with ExitStack() as stack:
        if resume:
            run.open_directory()  # a run without a train state is refused first
        # The environment comes from the data DAgger aggregates into: the source for a new run, so that
        # a wrong task or robot fails before anything is written; the run's own copy when resuming.
        with EpisodeStore.open(agg_path if resume else source_path) as origin:
            env_args = rollout_env_args(origin, config.task, tc.robot)
            if is_foreign(env_args[0]):
                family = foreign_family(family, config, origin, env_args[0])
            env = stack.enter_context(closing(make_env_for_store(origin, *env_args)))
            run.open_directory()
            if not resume:
                store = create_aggregate(origin, agg_path, chunk=tc.chunk if config.uses_chunk_labels() and
                                         family.CHUNK_LABELS else 1)
        if resume:
            store = EpisodeStore.open(agg_path, "a")
        stack.enter_context(store)
        if CHUNK_KEY in store.meta.features:  # the aggregate says (a resumed run's was made by its first start)
            horizon = store.meta.features[CHUNK_KEY].shape[0]
            family = dataclasses.replace(family, chunk_labels=ChunkLabels(horizon, config.label_stride or horizon,
                                                                          config.uses_segment_labels()))
        stack.enter_context(run)
        stack.enter_context(session(executor))  # one Ray (when used) for every round
        features = {k for k in store.meta.features if k not in (LABEL_KEY, INTERVENTION_KEY, CHUNK_KEY, HAS_CHUNK_KEY)}
        flagged = INTERVENTION_KEY in store.meta.features  # False in an aggregate made before the flag
        recorded = {*env.features, "action", "info.executed_action", "info.ee_target"}
        if features != recorded:
            raise DemoError(source_path, f"records {sorted(features)}; DAgger rollouts record {sorted(recorded)}")

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
            if config.warm_start or not config.refits_normalizers():
                return demos.reload(store, episodes, demo_val)
            return prepare(round0, store, split=(episodes, demo_val))

        def new_learner(data: TrainingData, r: int, step: int) -> Learner:
            return run.new_learner(data, step, tc.steps if r == 0 else config.round_steps, seed=tc.seed + 1000 * r)

        def labels_so_far(r: int) -> int:
            rounds_col, labels = store.column("dagger_round"), store.column("labels")
            return demo_labels + int(labels[(rounds_col >= 1) & (rounds_col <= r)].sum())

        data = demos
        learner = new_learner(demos, 0, 0)
        run.begin(store, demos, learner, {"name": family.name, **config.to_json(), **family.to_json(), "source_data": absolute(tc.data)})
        run.metrics["rounds"] = []
        done_round = -1
        if resume:
            saved = run.saved_extra()
            if not saved.get("round_done", False):
                raise DemoError(run.out, "was interrupted inside a round (DAgger resumes from a finished round); start it again with --overwrite")
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
        def spent(r: int, infos: list[dict[str, Any]]) -> bool:
            """Whether the labels through round ``r - 1`` and round ``r``'s ``infos`` reach ``max_labels``."""
            if config.max_labels is None:
                return False
            return labels_so_far(r - 1) + sum(int(i["labels"]) for i in infos) >= config.max_labels

        for r in range(max(done_round, 0) + 1, config.rounds + 1):
            if spent(r, []):
                break  # the label budget is spent: later rounds would add nothing
            beta = config.beta_at(r)
            # reused after an interruption: the round's rollouts (their segments come with them)
            existing = np.flatnonzero((store.column("dagger_round") == r) & (store.column("source") != SEGMENT_SOURCE))
            infos = [store.episode_info(int(i)) for i in existing]
            seeds = dagger_seeds(tc.seed, r, config.episodes_per_round)[len(existing):]
            episodes = family.episodes(run, store, env, r, beta, gate)
            for episode, info in round_rollouts(run, env, env_args, seeds, episodes, executor):
                batch = [(episode, info), *info.pop("segments", [])]  # the rollout and its segments
                for frames, row in batch:
                    row.update(task=store.meta.task.get("name", ""), dagger_round=r)
                    if not flagged:
                        frames.pop(INTERVENTION_KEY)
                store.append_episodes(batch)  # in one append: an interruption keeps all of them or none
                infos.append(info)
                run.tick(info=f"round {r}: rollout {len(infos)}/{config.episodes_per_round}")
                if spent(r, infos):
                    break
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
            last = {**_round_entry(r, beta, infos, labels_round, labels_so_far(r), learner.step, entry),
                    **family.round_entry(infos)}
            run.metrics["rounds"].append(last)
            run.checkpoint({"round": r, "round_done": True})
            mixing = f"gate {gate:g}" if gate is not None else f"beta {beta:.2f}"  # under a gate beta is unused
            run.tick(message=f"round {r}: {mixing}, rollout success {last['rollout_success']:.0%}, "
                             f"labels {last['labels_round']} (total {last['labels_total']})"
                             + (f", eval success {entry['success_rate']:.0%}" if entry else ""))

        total_labels = labels_so_far(config.rounds)
        run.record["data"]["expert_labels"] = total_labels
        run.record["data"]["seeds"] = [int(x) for x in store.column("seed") if int(x) >= 0]
        summary = run.finish({"round": config.rounds, "round_done": True}, demo_labels=demo_labels,
                             episodes=store.num_episodes)
    return {**summary, "algo": family.name, "rounds": run.metrics["rounds"]}


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
