"""An imitation training run: everything around the optimisation that every imitation algorithm shares.

:class:`TrainingRun` is a :class:`demo.training.run.Run` (the run directory's lifecycle, shared with
RL) over a learner and its training data, so that an algorithm file holds only what is its own:

1. **seeding and threads**: ``torch.manual_seed(seed)``, the batch RNG, ``torch.set_num_threads``;
2. **the run directory** (:mod:`demo.policies.checkpoint`): refused if it holds something else,
   replaced only with ``overwrite``, continued with ``resume`` (which must train the same thing);
3. **the record** ``run.json``: task, robot, data split, the resolved config, the exact command
   (a union of stores: every store and every robot, each robot's files kept in the run);
4. **the loop** (:meth:`TrainingRun.fit`): batches of training windows, one optimiser step each
   (:func:`demo.training.optim.train_step`), mean training loss every ``log_every`` steps, validation
   loss every ``val_every``, rollout success every ``eval_every`` (:class:`demo.training.run.Monitor`: episodes of
   the store's task on seeds disjoint from the data and from ``demo eval``);
5. **checkpoints**: the policy (evaluation weights) and ``train_state.pt`` (tensors only) at every
   evaluation, at the end, and on Ctrl-C; the train state alone once the directory is made and every
   ``checkpoint_every`` seconds, so that ``resume`` continues bit-exactly after a kill at any moment;
6. **metrics and the summary**: ``metrics.json``, ``curves.png``, the dict :meth:`finish` returns.

Progress is reported as :class:`demo.progress.Tick` s of one stage ("train ALGO") with the fields
``loss``, ``val``, ``success`` and ``info``; the CLI draws them.

Use (behaviour cloning, :mod:`demo.imitation.bc`)::

    with TrainingRun(config, progress=progress, resume=resume, overwrite=overwrite) as run:
        data = ...                         # demo.training.data.prepare
        learner = run.new_learner(data)
        run.begin(store, data, learner)    # opens the run directory, writes run.json
        run.fit(until=config.steps)        # on the attached data's training windows
        return run.finish()
"""

from __future__ import annotations

from collections.abc import Sequence
import json
import math
from pathlib import Path
import time
from typing import Any

import numpy as np
import torch

from demo.errors import DemoError
from demo.policies import checkpoint as ckpt
from demo.policies.actor import ExecConfig
from demo.policies.device import resolve_device
from demo.policies.instruction import text_config, with_pretrained_shape
from demo.policies.normalizer import MinMaxNormalizer
from demo.policies.policy import build_policy, policy_config
from demo.policies.visuomotor import encoder_config
from demo.progress import Progress
from demo.store import ActionSpec, EpisodeStore, StoreMeta
from demo.store.location import absolute
from demo.training import distributed
from demo.training.config import RESUME_KEYS, TrainConfig
from demo.training.data import TrainingData, chunk_action_limits, images_shuffled
from demo.training.optim import Learner, make_learner, train_step, validation_loss
from demo.training.plots import plot_training
from demo.training.run import Run


def execution_config(config: TrainConfig, action: ActionSpec) -> ExecConfig:
    """How the trained policy's chunks and gripper are executed (recorded in the run)."""
    binary = tuple(i for i, name in enumerate(action.names) if name == "gripper") if config.binary_gripper else ()
    return ExecConfig(config.execute, config.ensemble_decay if config.ensemble else None, binary, config.candidates)


class TrainingRun(Run):
    """One imitation run directory from seeding to summary; see the module docstring for its stages."""

    def __init__(self, config: TrainConfig, *, progress: Progress | None = None, resume: bool = False,
                 overwrite: bool = False, command: str | None = None, total_steps: int | None = None,
                 name: str | None = None, title: str | None = None):
        config.check()
        policy_config(config.algo, config.policy)  # unknown policy or option: fail before touching anything
        try:
            encoder_config(config.encoder)
        except (TypeError, ValueError) as exc:
            raise DemoError("--encoder", str(exc)) from None
        try:
            text_config(config.text)
        except (TypeError, ValueError) as exc:
            raise DemoError("--text-opt", str(exc)) from None
        # Under torchrun: this rank's group and device (demo.training.distributed); None in one process.
        group, self.device = distributed.init_from_env(resolve_device(config.device))
        monitored = config.eval_every or config.eval_final
        super().__init__(config.out, seed=config.seed, threads=config.threads, stage=f"train {name or config.algo}",
                         title=title or f"{config.algo} on {' + '.join(Path(p).name for p in config.stores)}",
                         total_steps=total_steps or config.steps, monitor_episodes=config.eval_episodes if monitored else 0,
                         progress=progress, resume=resume, overwrite=overwrite, command=command, group=group,
                         checkpoint_every=config.checkpoint_every)
        self.config = config
        self.rng = np.random.default_rng([config.seed, 0xB0C])
        self.metrics = {"train_loss": [], "val_loss": [], "eval": []}
        self.learner: Learner | None = None
        self.data: TrainingData | None = None
        self.execution = ExecConfig()
        self.action: ActionSpec | None = None

    # ---------------------------------------------------------------------------- 1-3. set-up
    def new_learner(self, data: TrainingData, step: int = 0, phase_steps: int | None = None, seed: int | None = None) -> Learner:
        """A freshly initialised policy for ``data`` and its optimiser (``seed``: re-seed torch first)."""
        if seed is not None:
            torch.manual_seed(seed)
        text: Any = self.config.text
        pretrained = data.instructions.pretrained if data.instructions is not None else None
        if pretrained is not None:
            try:
                text = with_pretrained_shape(text, pretrained)
            except ValueError as exc:
                raise DemoError("--text-opt", str(exc)) from None
        policy = build_policy(self.config.algo, data.spec, policy_config(self.config.algo, self.config.policy),
                              self.config.encoder, text)
        if pretrained is not None:  # a text encoder trained before starts this one (--text-opt init=RUN)
            policy.text.load_state_dict(pretrained.weights)
            policy.text.requires_grad_(not text.freeze)
        policy.fit_actions(*chunk_action_limits(data))
        return make_learner(policy, self.config, step, phase_steps, self.device)

    def begin(self, store: EpisodeStore | Sequence[EpisodeStore], data: TrainingData, learner: Learner,
              algo_record: dict[str, Any] | None = None) -> None:
        """Record the run (``run.json``, the robots' files) for the data it trains on (``store``, open;
        several for a union, in ``data``'s order), opening the run directory once every robot is found;
        with ``resume``, check that the run continues the same training (only ``steps`` and monitoring
        may change)."""
        stores = [store] if isinstance(store, EpisodeStore) else list(store)
        if self.config.robot is not None and len(stores) > 1:
            raise DemoError("--robot", "replaces the robot of a single store; each store of a union keeps its own")
        # A missing robot file fails before any write.
        records = [ckpt.run_robot(s.meta.robot, s.path, self.config.robot) for s in stores]
        self.open_directory()
        self.attach(learner, data)
        first = stores[0]
        self.action = first.meta.action
        self.execution = execution_config(self.config, first.meta.action)
        seeds = np.concatenate([s.column("seed") if s.num_episodes else np.zeros(0, int) for s in stores])
        self.record = run_record(self.config, first.meta, data, learner, self.execution, self.command, algo_record, seeds)
        self.record["robot"] = records[0]
        self.record["data"]["content"] = [s.content_hash() for s in stores]  # what was read, not only where
        if self.group is not None:  # --batch-size is per process
            self.record["data_parallel"] = {"processes": self.group.world, "backend": distributed.backend(),
                                            "global_batch_size": self.group.world * self.config.batch_size}
        robots, robot_of = ckpt.distinct_robots(records)
        if len(stores) > 1:
            self.record["robots"] = robots
            self.record["data"]["stores"] = [
                {**store_record(data, i), "robot": robots[robot_of[i]].get("name")} for i in range(len(stores))]
        if self.resume:
            previous = ckpt.read_run(self.out)
            check_resumable(self.out, previous, self.record)
            self.record["created"] = previous.get("created", self.record["created"])
            self.record["resumed"] = [*previous.get("resumed", []),
                                      {"at_step": int(self.resumed_state()["step"]), "command": self.command, "time": ckpt.now()}]
        if not self.is_main:
            return
        # The run carries its robots (config and files) so that it evaluates wherever it is moved.
        for i, robot in enumerate(robots):
            ckpt.save_robot(ckpt.robot_home(self.out, i), robot, stores[robot_of.index(i)].path)
        self.write_record()
        if not self.resume:
            self.save_state()  # from here a kill leaves a run that --resume continues (module docstring of run.py)

    def attach(self, learner: Learner, data: TrainingData) -> None:
        """Make ``learner`` (trained on ``data``) the one checkpointed, evaluated and reported."""
        self.learner, self.data = learner, data

    def saved_extra(self) -> dict[str, Any]:
        """The algorithm's own state saved with the checkpoint a resumed run continues (e.g. DAgger's round)."""
        return json.loads(self.resumed_state().get("extra", "{}"))

    def restore(self, learner: Learner) -> dict[str, Any]:
        """Load the last checkpoint into ``learner``, the batch RNG and the metrics; returns its extra."""
        state = self.resumed_state()
        try:
            learner.policy.load_state_dict(state["policy"])
            if learner.ema is not None:
                learner.ema.shadow = {k: v.to(learner.device, copy=True) for k, v in state["ema"].items()}
            learner.optimizer.load_state_dict(state["optimizer"])
            learner.step = int(state["step"])
            learner.phase_start = int(state.get("phase_start", 0))
            learner.phase_steps = int(state.get("phase_steps", self.config.steps))
            self.rng.bit_generator.state = json.loads(state["numpy_rng"])
            torch.set_rng_state(state["torch_rng"])
            self.metrics = json.loads(state["metrics"])
        except (KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise DemoError(self.out, f"train state does not match this run ({str(exc).splitlines()[0][:160]})") from None
        return json.loads(state.get("extra", "{}"))

    # ---------------------------------------------------------------------------- 4. the loop
    def fit(self, until: int) -> None:
        """Optimise the attached learner on its data's training windows until its step is ``until``,
        logging the training loss and the loss on the data's fixed validation windows, evaluating
        every ``eval_every`` steps."""
        learner, c = self._attached(), self.config
        if self.group is not None and learner.loss_module is None:
            self._distribute(learner)
        windows = self.data.windows(self.data.train_episodes)
        val_batch = self.data.validation_batch(c.seed) if self.is_main else None  # rank 0 validates
        world = 1 if self.group is None else self.group.world
        self.tick()
        running, count, t0 = torch.zeros(()), 0, time.perf_counter()
        if val_batch is not None and learner.step == 0 and not self.metrics.get("val_loss"):
            self.metrics.setdefault("val_loss", []).append([0, validation_loss(learner, val_batch)])  # the untrained policy
        while learner.step < until:
            running += train_step(learner, *windows.sample(c.batch_size, self.rng))
            count += 1
            step = learner.step
            if step % c.log_every == 0 or step == until:
                mean = distributed.mean(float(running / count), self.group)  # over every rank's batches
                if not math.isfinite(mean):
                    raise DemoError(c.out, f"training diverged (loss {mean} at step {step}); lower --lr")
                self.metrics.setdefault("train_loss", []).append([step, mean])
                rate = count * c.batch_size * world / max(time.perf_counter() - t0, 1e-9)
                self.metrics.setdefault("samples_per_s", []).append([step, rate])  # windows, every rank's
                running, count, t0 = torch.zeros(()), 0, time.perf_counter()
                self.tick(loss=mean, info=f"{rate:,.0f} samples/s")
            if val_batch is not None and (step % c.val_every == 0 or step == until):
                v = validation_loss(learner, val_batch)
                self.metrics.setdefault("val_loss", []).append([step, v])
                self.tick(val=v)
            if val_batch is not None and step == until and (shuffled := images_shuffled(val_batch, c.seed)) is not None:
                # Does the policy read its cameras? The same validation windows with the images of others.
                self.metrics["val_loss_images_shuffled"] = validation_loss(learner, shuffled)
            if val_batch is not None and step == until and self.data.instructions is not None:
                # One policy for many tasks: the validation loss of each task (instruction) on its own, at the end.
                self.metrics["val_loss_per_instruction"] = {
                    text: validation_loss(learner, batch)
                    for text, batch in self.data.validation_batches_by_instruction(c.seed).items()}
            if self.monitor is not None and c.eval_every and step % c.eval_every == 0 and step != until:
                self.evaluate()
                self.checkpoint()
            self.save_state_if_due()

    def _distribute(self, learner: Learner) -> None:
        """Data-parallel from here on: the loss through DDP, and this rank's own batch and noise RNGs,
        derived from (seed, rank, step) so that a resumed run may change the number of ranks."""
        rank = self.group.rank
        learner.loss_module = distributed.wrap(learner.policy, learner.device)
        self.rng = np.random.default_rng([self.config.seed, 0xB0C, rank, learner.step])
        torch.manual_seed(int(np.random.SeedSequence([self.config.seed, 0x7012C, rank, learner.step]).generate_state(1)[0]))

    def bundle(self) -> ckpt.PolicyBundle:
        """The attached learner as it is now (evaluation weights), runnable like a saved policy."""
        learner, data = self._attached(), self.data
        return ckpt.PolicyBundle(self.config.algo, learner.eval_policy(), data.obs_spec, data.obs_norm, data.action_norm,
                                 self.action, self.execution, self.record, self.out, data.relative)

    def tick(self, done: int | None = None, message: str | None = None, **fields: Any) -> None:
        """Report progress at the learner's step (or ``done``)."""
        if done is None and self.learner is not None:
            done = self.learner.step
        super().tick(done, message, **fields)

    # ---------------------------------------------------------------------------- 5-6. checkpoints, summary
    @property
    def step(self) -> int:
        return self._attached().step

    def can_checkpoint(self) -> bool:
        return self.learner is not None

    def policy_weights(self) -> tuple[dict[str, torch.Tensor], MinMaxNormalizer, MinMaxNormalizer]:
        learner, data = self._attached(), self.data
        return learner.eval_weights(), data.obs_norm, data.action_norm

    def train_state(self, extra: dict[str, Any] | None) -> dict[str, Any]:
        learner = self._attached()
        return {
            "step": learner.step,
            "phase_start": learner.phase_start,
            "phase_steps": learner.phase_steps,
            "policy": learner.policy.state_dict(),
            "ema": learner.ema.shadow if learner.ema is not None else {},
            "optimizer": learner.optimizer.state_dict(),
            "numpy_rng": json.dumps(self.rng.bit_generator.state),
            "torch_rng": torch.get_rng_state(),
            "metrics": json.dumps(self.metrics),
            "extra": json.dumps(extra or {}),
        }

    def plot(self, path: Path) -> None:
        plot_training(self.metrics, path, title=self.title)

    def final_metrics(self) -> dict[str, Any]:
        learner, m = self._attached(), self.metrics
        return {
            "step": learner.step,
            "train_loss": m["train_loss"][-1][1] if m["train_loss"] else None,
            "val_loss": m["val_loss"][-1][1] if m["val_loss"] else None,
            **({"val_loss_per_instruction": m["val_loss_per_instruction"]} if m.get("val_loss_per_instruction") else {}),
            **(cameras_read(m["val_loss"][-1][1], m["val_loss_images_shuffled"]) if "val_loss_images_shuffled" in m else {}),
            "success_rate": m["eval"][-1]["success_rate"] if m["eval"] else None,
            "seconds": self.seconds,
            "expert_labels": self.record["data"]["expert_labels"],
        }

    def summary(self) -> dict[str, Any]:
        data = self.record["data"]
        return {"out": str(self.out), "algo": self.record["algo"], **self.metrics["final"],
                "train_episodes": len(data["train_episodes"]), "val_episodes": len(data["val_episodes"]),
                "train_frames": data["train_frames"]}

    def _attached(self) -> Learner:
        if self.learner is None or self.data is None:
            raise RuntimeError("no learner attached: call TrainingRun.begin first")
        return self.learner


# A policy whose validation loss rises less than this when its images are shuffled across the validation windows
# does not read its cameras. Runs that succeed from cameras rise 25-87x (gym-aloha's transfer cube: ACT 25x,
# diffusion 33x, single-step BC 87x); ACT trained with its joints always in view rose 1.0x and scored 7/100.
CAMERAS_READ_RATIO = 1.1


def cameras_read(val_loss: float, val_loss_images_shuffled: float) -> dict[str, Any]:
    """The summary's camera check: both losses and whether shuffling the images raised the loss by
    :data:`CAMERAS_READ_RATIO` or more (``reads_cameras``)."""
    return {"val_loss_images_shuffled": val_loss_images_shuffled,
            "reads_cameras": bool(val_loss_images_shuffled >= CAMERAS_READ_RATIO * val_loss)}


def run_record(config: TrainConfig, meta: StoreMeta, data: TrainingData, learner: Learner, execution: ExecConfig,
               command: str | None, algo_record: dict[str, Any] | None = None,
               seeds: np.ndarray | None = None) -> dict[str, Any]:
    """What ``run.json`` says of a run: what it trained on, how, and how to execute the policy."""
    used = np.union1d(data.train_episodes, data.val_episodes)
    seeds = np.zeros(0, int) if seeds is None else np.asarray(seeds)
    return {
        "algo": (algo_record or {}).get("name", config.algo),
        "created": ckpt.now(),
        "command": command,
        "policy": ckpt.policy_record(config.algo, learner.policy, data.obs_spec, meta.action, execution, data.relative,
                                     data.instructions.tokenizer if data.instructions is not None else None),
        "task": meta.task,
        "robot": meta.robot,
        "fps": meta.fps,
        "data": {
            "path": absolute(config.stores[0]),  # a union's first store; all of them under "stores"
            "episodes_total": len(data.ends),
            "train_episodes": data.train_episodes.tolist(),
            "val_episodes": data.val_episodes.tolist(),
            "train_frames": data.frames(data.train_episodes),
            "val_frames": data.frames(data.val_episodes),
            # Every labelled frame of every episode used (validation too) cost one expert query.
            "expert_labels": data.frames(used),
            "seeds": [int(s) for s in seeds[seeds >= 0]],
        },
        "train": config.to_json(),
        **({"dagger": algo_record} if algo_record else {}),
        "versions": {"torch": torch.__version__, "numpy": np.__version__},
    }


def store_record(data: TrainingData, i: int) -> dict[str, Any]:
    """What ``run.json["data"]["stores"]`` says of the ``i``-th store of a union: its path, where its
    episodes start in the concatenation, how many it holds and how many of them train and validate."""
    source = data.sources[i]
    lo, hi = source.first_episode, source.first_episode + source.episodes
    train, val = (int(np.count_nonzero((eps >= lo) & (eps < hi))) for eps in (data.train_episodes, data.val_episodes))
    return {"path": absolute(source.path), "first_episode": lo, "episodes": source.episodes,
            "train_episodes": train, "val_episodes": val, **({"weight": data.mix[i]} if data.mix else {})}


def data_paths(record: dict[str, Any]) -> list[str]:
    """The store paths a run record trained on (a union's stores, else its one store)."""
    data = record.get("data") or {}
    stores = data.get("stores")
    if isinstance(stores, list) and stores:
        return [str(Path(s.get("path", ""))) for s in stores if isinstance(s, dict)]
    return [str(Path(data.get("path", "")))]


# The DAgger family's record (run.json's "dagger") compared on resume, but for: how far it goes (may grow), the
# learner's settings (RESUME_KEYS), the source (compared as "data") and the member's name (compared as "algo").
DAGGER_UNCOMPARED = {"rounds", "max_labels", "train", "source_data", "name"}


def differing(keys: Any, a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """The ``keys`` whose values in records ``a`` and ``b`` differ (as JSON: a tuple and its list are equal)."""
    return [k for k in keys if json.dumps(a.get(k)) != json.dumps(b.get(k))]


def check_resumable(out: Path, previous: dict[str, Any], run: dict[str, Any]) -> None:
    """--resume must continue the same training: same data, policy and data-shaping options."""
    differ = differing(RESUME_KEYS, previous.get("train", {}), run["train"])
    if previous.get("algo") != run["algo"] and "algo" not in differ:
        differ.insert(0, "algo")
    if data_paths(previous) != data_paths(run):
        differ.append("data")
    content = (previous.get("data") or {}).get("content")
    if content and content != run["data"].get("content") and "dagger" not in run and not differ:  # DAgger's grows
        raise DemoError(out, "its data changed since the run started (a store replaced or appended to): cannot "
                             "resume on other data; train a new run")
    may_change = "--steps and monitoring"
    if "dagger" in previous or "dagger" in run:
        # The DAgger family's own settings shape the aggregate as the learner's shape its batches: a resumed run
        # with other labels, gate or beta would mix two kinds of rounds in one store. How far it goes may change.
        a, b = previous.get("dagger") or {}, run.get("dagger") or {}
        differ += differing(sorted({*a, *b} - DAGGER_UNCOMPARED), a, b)
        may_change = "--steps, --rounds, --max-labels and monitoring"
    if differ:
        raise DemoError(out, f"cannot resume with a different {', '.join(differ)} (only {may_change} may change)")
