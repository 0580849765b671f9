"""Behaviour cloning: supervised training of a registered policy on demonstration windows.

``demo train STORE --algo bc`` (and ``--algo diffusion``, whose policy only brings another loss and
its own defaults) runs :func:`train`, which reads top to bottom:

1. the config is resolved: flags not given take the policy's measured-best defaults
   (:func:`demo.training.config.for_policy`; BC: 16-step chunks with temporal ensembling);
2. the store (or several, as one) becomes training data (:func:`demo.training.data.prepare_union`: split,
   normalisers, windows);
3. a :class:`demo.training.trainer.TrainingRun` opens the run directory, records the run (with the
   robot's files) and, with ``resume``, restores the last checkpoint;
4. the policy's own loss (:meth:`Policy.loss`: MSE for the MLP, denoising for diffusion) is
   minimised on random training windows until ``steps``, with validation, optional rollouts and
   checkpoints (the run's loop);
5. the summary.

Everything is seeded: the same config and data give the same weights.
"""

from __future__ import annotations

from typing import Any

from demo.progress import Progress
from demo.training.config import TrainConfig
from demo.training.data import open_stores, prepare_union
from demo.training.trainer import TrainingRun


def train(config: TrainConfig, *, progress: Progress | None = None, resume: bool = False, overwrite: bool = False,
          command: str | None = None, stop_at: int | None = None) -> dict[str, Any]:
    """Train a policy on ``config.data`` into the run directory ``config.out``; returns the summary.

    Ctrl-C saves a checkpoint before stopping; ``stop_at`` stops (and saves) at that step as if
    interrupted, for time-boxed jobs. Either way ``resume=True`` continues bit-exactly.
    """
    config = config.resolved()
    with TrainingRun(config, progress=progress, resume=resume, overwrite=overwrite, command=command) as run:
        with open_stores(config.stores) as stores:  # several: one policy on their union
            data = prepare_union(config, stores)
            learner = run.new_learner(data)
            run.begin(stores, data, learner)
        if resume:
            run.restore(learner)
            learner.phase_steps = config.steps  # a longer --steps stretches the remaining schedule
        until = config.steps if stop_at is None else min(stop_at, config.steps)
        run.fit(until)
        if until == config.steps and not any(e["step"] == learner.step for e in run.metrics["eval"]):
            run.evaluate()  # with monitoring on, the final policy is always rolled out
        return run.finish()
