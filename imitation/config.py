"""The configuration of the DAgger family (:mod:`demo.imitation.dagger`): rounds, rollouts, the beta
schedule, the HG-DAgger gate and the label budget, over the learner's :class:`TrainConfig`.

Plain data (no torch), so that ``demo train --help`` shows its defaults and :mod:`demo.algorithms`
names it without loading a network.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, NamedTuple

from demo.errors import DemoError
from demo.training.config import DAGGER_DEFAULTS, TrainConfig, for_policy, setting


class Member(NamedTuple):
    plugin: str  # "module:Class" of its demo.imitation.dagger.Family subclass (its own options: --algo-opt)
    summary: str


# The DAgger family: one rollout-and-aggregate loop (demo.imitation.dagger), a plugin per member.
FAMILY: dict[str, Member] = {
    "dagger": Member("demo.imitation.dagger:Family", "DAgger (beta schedule); HG-DAgger with --gate"),
    "safedagger": Member("demo.imitation.safedagger:SafeDagger", "SafeDAgger: a classifier decides where the expert takes over"),
    "aggrevate": Member("demo.imitation.aggrevate:AggreVaTe", "AggreVaTe(D): cost-to-go labels from expert roll-outs"),
    "dart": Member("demo.imitation.dart:Dart", "DART: demonstrations under noise estimated from the learner's errors"),
    "perturb": Member("demo.imitation.perturb:Perturb", "state perturbation with expert labels"),
}


LEARNERS = ("bc", "act", "diffusion", "flow", "transformer")  # the policies a family member can train (not PPO's)


@dataclass
class DaggerConfig:
    """DAgger's own hyperparameters; ``train`` holds round 0's (and the optimiser's)."""

    train: TrainConfig = field(default_factory=TrainConfig)
    task: str | None = setting(None, "The task to roll out (must be the data's).", unset="the data's")
    # BC's chunked, ensembled MLP unless told; ACT is what reaches gym-aloha's insertion from its camera
    learner: str = setting("bc", f"The policy the family trains and rolls out: {' | '.join(LEARNERS)}.")
    rounds: int = setting(5, "Rounds of rollouts + aggregation + retraining.")
    episodes_per_round: int = setting(10, "Learner rollouts per round.")
    round_steps: int = setting(2000, "Optimiser steps of the learner trained after each round.")
    warm_start: bool = setting(False, "Fine-tune the previous learner instead of training a new one per round.")
    refit_normalizers: bool | None = setting(None, "Refit the normalisers to each round's labelled frames.",
                                             unset="with segment labels; else the demonstrations' are kept")
    # linear:5 over indicator (Ross et al.'s): the learner's first rollouts, from a few demonstrations, stall and
    # fill the aggregate with copies of a stalled state; mixing in the expert keeps the rollouts moving through
    # the task (pick, 10 demos + 5 x 10 rollouts, seeds 0/1: 69%/59% against 46%/40%; bench compounding: stack).
    beta: str = setting("linear:5", "Expert-mixing schedule: indicator | linear:N | exp:P.")
    gate: str | None = setting(None, "HG-DAgger: the expert takes over and labels only where the learner strays by THRESH "
                                     "rad (safedagger: the deviation its classifier predicts).", metavar="deviation:THRESH",
                               unset="plain DAgger")
    max_labels: int | None = setting(None, "Stop rolling out once this many expert labels are spent (demonstrations "
                                           "included): equal-budget comparisons.", unset="no limit")
    chunk_labels: bool | None = setting(None, "A chunked learner's labels are the expert's own chunks from the "
                                              "visited states (looked ahead in the simulator; DAgger and HG-DAgger).",
                                        unset="on for DAgger, off with --gate")
    # pick, 10 demos + 5 x 10 rollouts, 100 held-out episodes: chunk labels 69/100 (5,705 labels); segments 80/100
    # (5,033), with the normalisers refit to the segments 94, 83, 89/100 over training seeds 0-2 (4,873-5,497).
    segment_labels: bool = setting(True, "With chunk labels: keep the expert's look-ahead whole, its states "
                                         "included, as a short demonstration from the visited state (a window at "
                                         "each of its states for the same labels).")
    label_stride: int | None = setting(None, "With chunk labels: at most one every this many rollout steps.",
                                       unset="the learner's chunk")

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

    def uses_chunk_labels(self) -> bool:
        """Chunk labels unless told: on for DAgger, whose labelled states are the learner's and whose next
        labels are answers in states the expert would not have reached; off for HG-DAgger (a gate), whose
        labels are the expert's own consecutive actions while it is in control, already its plan (pick, 10
        demos + 5 x 10 rollouts, 100 held-out episodes: DAgger 5% without, 46% with; HG-DAgger 96% without,
        87% with one every 16 steps)."""
        return self.gate is None if self.chunk_labels is None else self.chunk_labels

    def uses_segment_labels(self) -> bool:
        """Segment labels: on with chunk labels for a chunked learner (``train.chunk`` > 1, as resolved)."""
        return self.uses_chunk_labels() and self.segment_labels and (self.train.chunk or 1) > 1

    def refits_normalizers(self) -> bool:
        """Refit unless told where the labelled frames are the expert's own states (segment labels): their
        ranges then are the expert's from many more start states than the demonstrations' (a cube beyond the
        10 demonstrations' range is otherwise an extrapolation). Elsewhere the labelled frames are the
        learner's, and an early learner's rollouts flail (joints to their limits, the EE half a metre up):
        min-max ranges refitted to them leave the states that matter a fraction of the input range."""
        return self.uses_segment_labels() if self.refit_normalizers is None else self.refit_normalizers

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

    def check_learner(self) -> None:
        if self.learner not in LEARNERS:
            raise DemoError("--learner", f"{self.learner!r} is not an imitation policy (choose from {', '.join(LEARNERS)})")

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
        self.check_learner()
        if self.max_labels is not None and self.max_labels < 1:
            raise DemoError("--max-labels", f"must be at least 1, got {self.max_labels}")
        if self.label_stride is not None and self.label_stride < 1:
            raise DemoError("--label-stride", f"must be at least 1, got {self.label_stride}")
        b = self.beta_at(1)
        if not 0 <= b <= 1:
            raise DemoError("--beta", f"beta must lie in [0, 1], got {b} in round 1")

    def to_json(self) -> dict[str, Any]:
        """The settings as the run uses them (``run.json``'s ``dagger``): the labelling's unset choices
        resolved, so that a resumed run is compared with what its first start did, not with what it was told."""
        d = asdict(self)
        d["train"] = self.train.to_json()
        d.update(chunk_labels=self.uses_chunk_labels(), segment_labels=self.uses_segment_labels(),
                 refit_normalizers=self.refits_normalizers())
        return d


def learner_config(**given: Any) -> TrainConfig:
    """The learner's resolved config: ``given`` values, then :data:`DAGGER_DEFAULTS`, then the policy's."""
    given = {k: v for k, v in given.items() if v is not None}
    return for_policy(given.pop("algo", "bc"), **{**DAGGER_DEFAULTS, **given})
