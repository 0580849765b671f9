"""DART as published (Laskey et al. 2017): the injected noise estimated from the learner's error, iterated.

``demo train DATA --algo dart --task T --rounds R --episodes-per-round K [--algo-opt alpha=A]`` runs
DAgger's loop (:func:`demo.imitation.dagger.train_dagger`) with this file's :class:`Dart` rounds:

1. round 0 trains BC on DATA, as every member of the family does;
2. before round ``r``'s collection, the noise covariance is estimated from the current learner's
   error on the expert's data: ``Sigma = mean_t (pi(s_t) - pi*(s_t)) (pi(s_t) - pi*(s_t))^T`` over
   the arm joint targets (rad^2), ``s_t`` the labelled frames of the episodes the learner was not
   trained on (DAgger's validation episodes; its training episodes where there are none), ``pi*`` the
   expert's label there and ``pi`` the learner's action (:func:`noise_covariance`). With ``alpha``
   (the published prior on the learner's final error), ``Sigma`` is rescaled to trace ``alpha / T``,
   ``T`` the task horizon (DART's ``Sigma_alpha = alpha / (T tr(Sigma)) Sigma``);
3. ``K`` expert demonstrations are collected with ``N(0, Sigma)`` added to the executed arm joint
   targets (the gripper command is not disturbed); the recorded action is the expert's clean label
   at every visited state, all of them labels (as ``demo collect --noise``, which injects a fixed,
   isotropic noise instead);
4. the learner is retrained on everything collected so far.

The noise is off-policy: the learner never acts. ``metrics.json`` records each round's covariance
(``noise_cov``) and its per-joint standard deviations (``noise_std``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from demo.sim.rollout import StepCommand, rollout
from demo.imitation.dagger import Family, episode_record, learner_actions
from demo.training.data import frame_indices


def noise_covariance(mine: np.ndarray, label: np.ndarray, n_arm: int) -> np.ndarray:
    """DART's covariance ``[n_arm, n_arm]`` (rad^2): the mean outer product of the learner's arm errors
    ``mine - label`` (``[N, A]`` each), about zero (the learner's bias is noise to inject too)."""
    e = np.asarray(mine, np.float64)[:, :n_arm] - np.asarray(label, np.float64)[:, :n_arm]
    return e.T @ e / max(len(e), 1)


@dataclass
class DartEpisodes:
    """One demonstration with ``N(0, cov)`` on the executed arm joint targets, clean labels."""

    cov: np.ndarray  # [n_arm, n_arm] rad^2
    n_arm: int

    def __call__(self, env: Any, actor: Any, seed: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        env.reset(seed)
        expert = env.expert(rng=np.random.default_rng([seed, 2]))
        rng = np.random.default_rng([seed, 5])
        w, v = np.linalg.eigh(self.cov)
        root = (v * np.sqrt(np.clip(w, 0.0, None))).astype(np.float64)  # root @ root.T == cov
        steps: list[bool] = []

        def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
            label = np.asarray(expert.act(env), dtype=np.float32)
            executed = label.copy()
            executed[: self.n_arm] += (root @ rng.standard_normal(self.n_arm)).astype(np.float32)
            steps.append(True)
            return StepCommand(executed=executed, label=label, ee_target=np.asarray(expert.ee_target, np.float32))

        episode = rollout(env, seed, act, reset=False)
        return episode_record(episode, seed, steps, steps, 1.0, source="dart")


@dataclass
class Dart(Family):
    """DART's rounds (module docstring); ``alpha``: the prior on the final error (None: Sigma as estimated)."""

    name: str = "dart"
    OPTIONS: ClassVar[tuple[str, ...]] = ("alpha",)
    CHUNK_LABELS: ClassVar[bool] = False  # its own labelling: single-step labels
    FOREIGN: ClassVar[bool] = False  # needs the simulator's state and the task's own expert
    alpha: float | None = None
    last: dict[str, Any] = field(default_factory=dict)

    def episodes(self, run: Any, store: Any, env: Any, r: int, beta: float, gate: float | None) -> DartEpisodes:
        data, n_arm = run.data, len(env.robot.arm_joints)
        held_out = data.val_episodes if len(data.val_episodes) else data.train_episodes
        frames = frame_indices(data.ends, held_out)
        if data.labelled is not None:
            frames = frames[data.labelled[frames]]
        cov = noise_covariance(learner_actions(run.bundle(), data, frames), data.action[frames], n_arm)
        if self.alpha is not None and np.trace(cov) > 0:
            cov = cov * (self.alpha / (env.horizon * np.trace(cov)))
        self.last = {"noise_cov": cov.tolist(), "noise_std": np.sqrt(np.diag(cov)).tolist(), "noise_frames": int(len(frames))}
        return DartEpisodes(cov, n_arm)

    def round_entry(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        return dict(self.last)

    def to_json(self) -> dict[str, Any]:
        return {"alpha": self.alpha}
