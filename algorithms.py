"""Every learning algorithm by name: what it learns from, its configuration, and the function that trains it.

This is the one list of algorithm names. ``demo train --algo`` and ``demo irl train --algo`` take
their choices from it; quickstart, the experiments and a Python user train through :func:`train`
as the CLI does::

    from demo import algorithms
    from demo.training.config import TrainConfig

    algorithms.train("diffusion", TrainConfig(data="avoid.zarr", out="runs/dp", algo="diffusion"))

Each algorithm's hyperparameters and their defaults live in its configuration dataclass (the
``config`` column), which resolves and validates itself in the library: the CLI only fills it.

==================  ==============  =======================================================
name                learns from     configuration / trainer
==================  ==============  =======================================================
bc, diffusion, act, a store         :class:`TrainConfig` / :func:`demo.imitation.bc.train`
flow, transformer
dagger, safedagger, a store and the :class:`DaggerConfig` / :func:`demo.imitation.dagger.train_dagger`
aggrevate, dart,    task's expert   (the member's own options: ``--algo-opt``)
perturb
ppo                 the simulator   :class:`PPOConfig` / :func:`demo.rl.ppo.train`
residual            a run + sim     :class:`ResidualConfig` / :func:`demo.rl.residual.train`
finetune            a run + sim     :class:`FinetuneConfig` / :func:`demo.rl.finetune.train`
gail, airl          a store + sim   :class:`AdversarialConfig` / :func:`demo.rl.adversarial.train`
maxent,             a store + sim   :class:`LinearIRLConfig` / :func:`demo.rl.irl_linear.train`
apprenticeship
==================  ==============  =======================================================

The table holds configuration classes and the trainers' names, not the trainers: a trainer (and
torch with it) is imported when an algorithm runs, so ``demo --help`` stays light.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from demo.errors import DemoError
from demo.imitation.config import FAMILY, DaggerConfig
from demo.rl.config import AdversarialConfig, FinetuneConfig, LinearIRLConfig, PPOConfig, ResidualConfig
from demo.training.config import TrainConfig

TRAIN = "train"  # `demo train STORE`: imitation from a store
IRL = "irl train"  # `demo irl train`: reinforcement and inverse reinforcement learning in the simulator


@dataclass(frozen=True)
class Algorithm:
    """One algorithm: its name, the command that trains it, its configuration class and its trainer."""

    name: str
    command: str  # TRAIN or IRL
    config: type  # the dataclass of every hyperparameter, with its defaults
    trainer: str  # "module:function"; called as trainer(config, **how) -> the run's summary dict
    summary: str
    family: bool = False  # a member of the DAgger family: expert-labelled rollouts + aggregation
    named_by: str | None = None  # the config field that names the algorithm too (it must agree)

    def load(self) -> Callable[..., dict[str, Any]]:
        """The trainer function (imported now: torch and the networks come with it)."""
        module, _, function = self.trainer.partition(":")
        return getattr(importlib.import_module(module), function)


ALGORITHMS: dict[str, Algorithm] = {a.name: a for a in (
    Algorithm("bc", TRAIN, TrainConfig, "demo.imitation.bc:train",
              "behaviour cloning: an MLP over action chunks (--head mse, gmm or discrete)", named_by="algo"),
    *(Algorithm(name, TRAIN, DaggerConfig, "demo.imitation.dagger:train_dagger", member.summary, family=True)
      for name, member in FAMILY.items()),
    Algorithm("diffusion", TRAIN, TrainConfig, "demo.imitation.bc:train",
              "Diffusion Policy: DDPM training, DDIM sampling, action chunks", named_by="algo"),
    Algorithm("flow", TRAIN, TrainConfig, "demo.imitation.bc:train",
              "flow matching (pi0's action expert): Euler integration of a learned velocity, action chunks",
              named_by="algo"),
    Algorithm("act", TRAIN, TrainConfig, "demo.imitation.bc:train",
              "ACT: transformer + CVAE, action chunks, temporal ensembling", named_by="algo"),
    Algorithm("transformer", TRAIN, TrainConfig, "demo.imitation.bc:train",
              "a transformer over proprioception, camera and instruction tokens, action chunks", named_by="algo"),
    Algorithm("ppo", IRL, PPOConfig, "demo.rl.ppo:train", "PPO on the dense task reward (or a learned one)"),
    Algorithm("residual", IRL, ResidualConfig, "demo.rl.residual:train",
              "residual RL: PPO on a bounded correction of a frozen imitation run (--init RUN)"),
    Algorithm("finetune", IRL, FinetuneConfig, "demo.rl.finetune:train",
              "full fine-tuning: PPO on a BC run's own weights, its demonstrations in a BC term (--init RUN)"),
    Algorithm("gail", IRL, AdversarialConfig, "demo.rl.adversarial:train", "GAIL: a discriminator's reward, PPO", named_by="kind"),
    Algorithm("airl", IRL, AdversarialConfig, "demo.rl.adversarial:train", "AIRL: a disentangled reward, PPO", named_by="kind"),
    Algorithm("maxent", IRL, LinearIRLConfig, "demo.rl.irl_linear:train", "MaxEnt IRL with a linear reward", named_by="method"),
    Algorithm("apprenticeship", IRL, LinearIRLConfig, "demo.rl.irl_linear:train",
              "apprenticeship learning (feature matching)", named_by="method"),
)}


def names(command: str) -> tuple[str, ...]:
    """The algorithms that ``command`` (:data:`TRAIN` or :data:`IRL`) trains, in the table's order."""
    return tuple(a.name for a in ALGORITHMS.values() if a.command == command)


def family() -> tuple[str, ...]:
    """The DAgger family's members (:mod:`demo.imitation.dagger`)."""
    return tuple(a.name for a in ALGORITHMS.values() if a.family)


def algorithm(name: str, command: str | None = None) -> Algorithm:
    """The algorithm ``name``; a one-line error for ``--algo`` naming the choices when there is none
    (among ``command``'s, when given)."""
    choices = names(command) if command else tuple(ALGORITHMS)
    if name not in choices:
        raise DemoError("--algo", f"unknown algorithm {name!r} (choose from {', '.join(choices)})")
    return ALGORITHMS[name]


def train(name: str, config: Any, *, options: dict[str, str] | None = None, **how: Any) -> dict[str, Any]:
    """Train algorithm ``name`` with ``config`` (an instance of its configuration class; unresolved
    settings take the algorithm's defaults there); returns the run's summary.

    ``options``: a DAgger-family member's own options (``--algo-opt KEY=VALUE``); ``how``: what the
    trainer takes besides the config (``progress``, ``overwrite``, ``command``; ``resume`` and
    ``stop_at`` for the imitation trainers; ``executor`` for the DAgger family)."""
    entry = algorithm(name)
    if not isinstance(config, entry.config):
        raise TypeError(f"{name} trains from a {entry.config.__name__}, not a {type(config).__name__}")
    if entry.named_by and getattr(config, entry.named_by) != name:
        raise ValueError(f"{name}: the config's {entry.named_by} is {getattr(config, entry.named_by)!r}")
    check_options(name, options)
    if entry.family:
        from demo.imitation.dagger import make_family  # deferred: torch stays out of demo --help

        how["family"] = make_family(name, options)
    return entry.load()(config, **how)


def check_options(name: str, options: dict[str, str] | None) -> None:
    """Refuse algorithm options (``--algo-opt``) for an algorithm that has none of its own."""
    if options and not algorithm(name).family:
        raise DemoError("--algo-opt", f"sets an option of {', '.join(family()[1:])}, not of {name!r}")
