"""The run directory's lifecycle, written once for every trainer: imitation (:class:`TrainingRun`) and RL
(:class:`demo.rl.ppo.RLRun`) alike.

A :class:`Run` owns what every run directory has (:mod:`demo.policies.checkpoint` holds the file names
and formats):

1. **seeding and threads**: ``torch.manual_seed(seed)`` before any network is built, ``torch.set_num_threads``;
2. **the directory**: refused if it holds something that is not a run, replaced only with
   ``overwrite``, continued with ``resume`` (which must find a train state);
3. **the record** ``run.json`` (:attr:`record`, written by :meth:`write_record`);
4. **monitoring**: :meth:`evaluate` rolls the current policy out on seeds disjoint from the data and
   from ``demo eval`` (:class:`Monitor`) and logs the result in ``metrics["eval"]``;
5. **checkpoints**: :meth:`checkpoint` saves the policy (``policy.safetensors`` and its normalisers),
   the train state (tensors only), ``metrics.json`` and the curves; Ctrl-C inside the ``with`` block
   saves one before stopping. Between them the train state alone is saved as soon as the directory
   is made (:meth:`save_state`) and then every ``checkpoint_every`` seconds (:meth:`save_state_if_due`),
   so that a run killed at any moment is complete, resumable (``--resume`` continues bit-exactly from
   its last save) or absent;
6. **the summary**: :meth:`finish` writes the final metrics, the record and a last checkpoint.

A subclass says what is its own: the step it counts (:attr:`step`), the policy as it is now
(:meth:`bundle`, :meth:`policy_weights`), the rest of its train state (:meth:`train_state`), its
figure (:meth:`plot`), its final figures (:meth:`final_metrics`) and its summary (:meth:`summary`).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

import torch

from demo.errors import DemoError
from demo.evaluation.evaluate import make_eval_env, resolve_target, run_episodes_inline, summarize
from demo.policies import checkpoint as ckpt
from demo.policies.normalizer import MinMaxNormalizer
from demo.progress import Progress, Tick, or_silent
from demo.seeds import MONITOR_OFFSET, eval_seeds
from demo.training import distributed


class Monitor:
    """Periodic rollout evaluation on the data's task (seeds disjoint from the data and from demo eval)."""

    def __init__(self, episodes: int, seed: int):
        self.episodes, self.seed = episodes, seed
        self.env: Any = None

    def __call__(self, bundle: ckpt.PolicyBundle) -> dict[str, Any]:
        if self.env is None:
            task, options, robot = resolve_target(bundle, None, None, None)
            self.env = make_eval_env(bundle, task, options, robot)
        outcomes = run_episodes_inline(bundle, self.env, eval_seeds(self.seed, self.episodes, MONITOR_OFFSET))
        return summarize(outcomes)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def check_run_directory(out: Path, resume: bool, overwrite: bool) -> bool:
    """Refuse (DemoError) a run directory this run may not use; True when it holds an older run that
    ``overwrite`` replaces. Read-only: callers (and a launcher, before its processes start) decide."""
    unstarted = unstarted_run(out)
    if resume:
        if not (out / ckpt.STATE_FILE).is_file():
            raise DemoError(out, "was stopped before its first save: start it again without --resume" if unstarted
                            else f"nothing to resume (no {ckpt.STATE_FILE})")
        return False
    stale = out.exists() and any(out.iterdir())
    if stale and not unstarted:
        if not overwrite:
            raise DemoError(out, "already exists (pass --resume to continue it, --overwrite to replace it)")
        if not (out / ckpt.RUN_FILE).is_file():
            raise DemoError(out, "exists and is not a training run; refusing to overwrite it")
    return stale


def unstarted_run(out: Path) -> bool:
    """A run directory killed before its first save: a record but neither a train state nor a policy. It holds
    no training, so a new run may replace it without ``--overwrite``."""
    return ((out / ckpt.RUN_FILE).is_file() and not (out / ckpt.STATE_FILE).exists()
            and not (out / ckpt.POLICY_FILE).exists())


class Run:
    """One run directory from seeding to summary; see the module docstring for its stages.

    ``stage``: the progress bar's label; ``monitor_episodes``: rollouts per :meth:`evaluate` (0: none);
    ``group``: this process's data-parallel group (None in one process: it writes the directory)."""

    EVAL_LABEL = ""  # after the evaluation's successes in the progress fields (RL shows its rollouts' there too)

    def __init__(self, out: str | Path, *, seed: int, threads: int, stage: str, title: str, total_steps: int,
                 monitor_episodes: int = 0, progress: Progress | None = None, resume: bool = False,
                 overwrite: bool = False, command: str | None = None, group: distributed.Group | None = None,
                 checkpoint_every: float = 0.0):
        self.out = Path(out)
        self.checkpoint_every = checkpoint_every  # seconds between periodic train-state saves; 0: none
        self.group = group
        self.resume, self.overwrite, self.command = resume, overwrite, command
        self.progress = or_silent(progress if self.is_main else None)  # rank 0 reports for all
        self.stage, self.title, self.total_steps = stage, title, total_steps
        if threads > 0:
            torch.set_num_threads(threads)
        torch.manual_seed(seed)
        self.monitor = Monitor(monitor_episodes, seed) if monitor_episodes and self.is_main else None
        self.metrics: dict[str, Any] = {"eval": []}
        self.record: dict[str, Any] = {}
        self._fields = {"loss": "-", "val": "-", "success": "-", "info": ""}
        self._started = time.perf_counter()
        self._saved_at = self._started
        self._opened = False
        self._saved: dict[str, Any] | None = None  # the train state a resumed run continues from, read once

    @property
    def is_main(self) -> bool:
        """Whether this process writes the run directory and reports (always, unless data-parallel rank > 0)."""
        return self.group is None or self.group.is_main

    @property
    def seconds(self) -> float:
        """Seconds since the run started."""
        return time.perf_counter() - self._started

    # ---------------------------------------------------------------------------- what a trainer provides
    @property
    def step(self) -> int:
        """The count the run reports progress and evaluations in (optimiser steps, environment steps)."""
        raise NotImplementedError

    def bundle(self) -> ckpt.PolicyBundle:
        """The policy as it is now, runnable as ``demo eval`` runs a saved one."""
        raise NotImplementedError

    def policy_weights(self) -> tuple[dict[str, torch.Tensor], MinMaxNormalizer, MinMaxNormalizer]:
        """What ``policy.safetensors`` holds: the weights evaluated, the observation and action normalisers."""
        raise NotImplementedError

    def extra_tensors(self) -> dict[str, torch.Tensor]:
        """Tensors saved in ``policy.safetensors`` beside the policy's own (a residual's); none by default."""
        return {}

    def train_state(self, extra: dict[str, Any] | None) -> dict[str, Any]:
        """What ``train_state.pt`` holds besides nothing: everything a resumed run continues from."""
        raise NotImplementedError

    def plot(self, path: Path) -> None:
        """The run's curves, from :attr:`metrics`."""
        raise NotImplementedError

    def final_metrics(self) -> dict[str, Any]:
        """The figures ``metrics["final"]`` starts with."""
        raise NotImplementedError

    def summary(self) -> dict[str, Any]:
        """What :meth:`finish` returns (and ``demo train --json`` writes)."""
        raise NotImplementedError

    def can_checkpoint(self) -> bool:
        """Whether there is anything to save yet (Ctrl-C before then saves nothing)."""
        return True

    def after_evaluation(self) -> None:
        """Called after every rollout evaluation (e.g. to put a policy back in training mode)."""

    # ---------------------------------------------------------------------------- the directory, the record
    def __enter__(self) -> "Run":
        return self

    def __exit__(self, kind: type | None, *exc: object) -> None:
        try:
            if kind is KeyboardInterrupt and self.can_checkpoint():
                self.checkpoint()
        finally:
            self.close()

    def close(self) -> None:
        """Release what the run holds (the monitor's environment, the process group)."""
        if self.monitor is not None:
            self.monitor.close()
        distributed.shutdown(self.group)

    def open_directory(self) -> None:
        """Create the run directory (once); with ``resume`` it must hold a train state, with
        ``overwrite`` an older run is replaced (never a directory that is not a run)."""
        if self._opened:
            return
        self._opened = True
        if self.resume:
            check_run_directory(self.out, resume=True, overwrite=False)
            self._saved = ckpt.load_train_state(self.out)  # one that cannot be resumed from is refused before any write
            return
        stale = check_run_directory(self.out, resume=False, overwrite=self.overwrite)
        distributed.barrier(self.group)  # every rank has looked at the directory before rank 0 changes it
        if not self.is_main:
            return
        if stale:
            shutil.rmtree(self.out)
        self.out.mkdir(parents=True, exist_ok=True)

    def write_record(self) -> None:
        """Write ``run.json`` (rank 0)."""
        if self.is_main:
            ckpt.write_run(self.out, self.record)

    def resumed_state(self) -> dict[str, Any]:
        """The train state a resumed run continues from (read when the directory was opened)."""
        if self._saved is None:
            raise RuntimeError("no train state to resume from: open the directory of a run with resume=True first")
        return self._saved

    # ---------------------------------------------------------------------------- monitoring, progress
    def evaluate(self) -> dict[str, Any] | None:
        """Roll the current policy out with the monitor (None without one); logged in ``metrics``."""
        if self.monitor is None:
            return None
        result = self.monitor(self.bundle())
        self.after_evaluation()
        entry = {"step": self.step, **{k: result[k] for k in ("success_rate", "ci95", "episodes", "mean_length")}}
        self.metrics["eval"].append(entry)
        self.tick(done=self.step, success=f"{result['successes']}/{result['episodes']}{self.EVAL_LABEL}")
        return entry

    def tick(self, done: int | None = None, message: str | None = None, **fields: Any) -> None:
        """Report progress: ``done`` (default: nothing new), updated fields, an optional message line."""
        for k, v in fields.items():
            self._fields[k] = f"{v:.4g}" if isinstance(v, float) else str(v)
        self.progress(Tick(self.stage, done, self.total_steps, dict(self._fields), message))

    # ---------------------------------------------------------------------------- checkpoints, summary
    def checkpoint(self, extra: dict[str, Any] | None = None) -> None:
        """Save the policy, the train state (with the trainer's ``extra``), the metrics and the curves."""
        if not self.is_main:
            return
        weights, obs_norm, action_norm = self.policy_weights()
        ckpt.save_policy(self.out, weights, obs_norm, action_norm, self.extra_tensors())
        ckpt.save_train_state(self.out, self.train_state(extra))
        self._saved_at = time.perf_counter()
        ckpt.write_json(self.out / ckpt.METRICS_FILE, self.metrics)
        self.plot(self.out / ckpt.CURVES_FILE)

    def save_state(self) -> None:
        """Save the train state alone (what ``--resume`` needs; no policy, metrics or curves), timed in
        ``metrics["checkpoint_seconds"]``."""
        if not self.is_main:
            return
        t0 = time.perf_counter()
        ckpt.save_train_state(self.out, self.train_state(None))
        self._saved_at = time.perf_counter()
        self.metrics["checkpoint_seconds"] = self.metrics.get("checkpoint_seconds", 0.0) + self._saved_at - t0

    def save_state_if_due(self) -> None:
        """:meth:`save_state` when ``checkpoint_every`` seconds have passed since the last save."""
        if self.checkpoint_every > 0 and time.perf_counter() - self._saved_at >= self.checkpoint_every:
            self.save_state()

    def finish(self, extra: dict[str, Any] | None = None, **final: Any) -> dict[str, Any]:
        """Final metrics (``final`` added), the record, a last checkpoint (with ``extra``); the summary."""
        self.metrics["final"] = {**self.final_metrics(), **final}
        self.write_record()
        self.checkpoint(extra)
        distributed.barrier(self.group)  # every rank returns once the run directory is complete
        return self.summary()
