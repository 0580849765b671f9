"""SafeDAgger (Zhang & Cho 2017): a learned classifier decides where the expert takes over.

``demo train DATA --algo safedagger --task T --gate deviation:TAU --rounds R --episodes-per-round K``
runs DAgger's loop (:func:`demo.imitation.dagger.train_dagger`) with this file's :class:`SafeDagger`
rounds. HG-DAgger's supervisor watches every step and steps in where the learner strays; here a
*safety classifier* predicts from the observation alone whether the learner's action would deviate
from the expert's, and the expert is asked (and takes over) only where it fires:

1. Before round ``r``'s rollouts, the classifier is fitted for the current learner: on frames the
   learner was *not* trained on (DAgger's validation episodes, held out of the demonstrations:
   ``--val-fraction``), the label is "the learner's action deviates" by HG-DAgger's own rule
   (:func:`demo.imitation.dagger.deviation` > TAU: the largest arm joint target difference, rad, or a
   gripper command off by more than :data:`demo.imitation.dagger.GRIPPER_GATE`). The classifier is an MLP
   on the learner's normalised observation of one frame (the same vector the learner reads), trained
   with class-balanced binary cross-entropy.
2. In the rollouts the learner drives; at every step where the classifier fires the expert's action
   is executed and recorded as a label (``info.intervention``, ``info.labelled``); elsewhere the
   learner's action runs and no label is counted.
3. The rollouts are aggregated and the learner retrained, as in DAgger.

Counted: labels (frames the expert controlled), takeovers (episodes' switches from the learner to the
expert) and, as a diagnostic only, the frames where the learner drove while deviating by more than
TAU (``missed_deviations``): the rollouts record the expert's answer at every visited state, as all
of DAgger's do, but those answers are neither trained on nor counted as labels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch

from demo.errors import DemoError
from demo.imitation.dagger import ActionParts, Family, MixtureEpisodes, deviation, learner_actions
from demo.training.data import LABEL_KEY, frame_indices
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import ObsSpec


@dataclass
class DeviationClassifier:
    """An MLP (numpy weights, so it travels to rollout workers) from one frame's observation vector,
    normalised as the learner normalises it, to the logit of "the learner deviates here"."""

    layers: list[tuple[np.ndarray, np.ndarray]]  # (W [in, out], b [out]) per layer, ReLU between
    obs_spec: ObsSpec
    low: np.ndarray  # the learner's observation normaliser (MinMaxNormalizer limits)
    high: np.ndarray

    def logits(self, x: np.ndarray) -> np.ndarray:
        """Logits for normalised observation vectors ``x [N, D]``."""
        h = np.asarray(x, dtype=np.float32)
        for i, (w, b) in enumerate(self.layers):
            h = h @ w + b
            if i < len(self.layers) - 1:
                h = np.maximum(h, 0.0)
        return h[:, 0]

    def __call__(self, frame: dict[str, np.ndarray], mine: np.ndarray, label: np.ndarray) -> bool:
        """The gate of :func:`demo.imitation.dagger.dagger_episode`: whether the expert takes this step.
        Reads the observation only; ``mine`` and ``label`` are there for the gate's signature."""
        norm = MinMaxNormalizer(self.low, self.high)
        x = np.clip(norm.normalize(self.obs_spec.vector(frame)[None]), -OBS_CLIP, OBS_CLIP)
        return bool(self.logits(x)[0] > 0.0)


def fit_classifier(x: np.ndarray, y: np.ndarray, hidden: tuple[int, ...], steps: int, seed: int,
                   batch_size: int = 256, lr: float = 1e-3) -> list[tuple[np.ndarray, np.ndarray]]:
    """Layers of an MLP fitted to labels ``y [N]`` (bool) from inputs ``x [N, D]`` by binary
    cross-entropy, positives weighted by negatives/positives (deviations are rare). With one class
    only, a constant classifier of that class."""
    x = np.asarray(x, dtype=np.float32)
    y = np.asarray(y, dtype=bool)
    sizes = [x.shape[1], *hidden, 1]
    g = torch.Generator().manual_seed(seed)
    positives = int(y.sum())
    if positives in (0, len(y)):  # nothing to separate: always (never) fire
        layers = [(np.zeros((a, b), np.float32), np.zeros(b, np.float32)) for a, b in zip(sizes[:-1], sizes[1:])]
        layers[-1][1][:] = 10.0 if positives else -10.0
        return layers
    modules: list[torch.nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        modules += [torch.nn.Linear(a, b), torch.nn.ReLU()]
    net = torch.nn.Sequential(*modules[:-1])
    with torch.no_grad():  # seeded initialisation, independent of torch's global RNG
        for p in net.parameters():
            p.uniform_(-1.0, 1.0, generator=g).mul_(1.0 / np.sqrt(p.shape[-1]))
    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    loss_fn = torch.nn.BCEWithLogitsLoss(pos_weight=torch.tensor((len(y) - positives) / positives))
    tx, ty = torch.from_numpy(x), torch.from_numpy(y.astype(np.float32))
    for _ in range(steps):
        i = torch.randint(0, len(x), (min(batch_size, len(x)),), generator=g)
        loss = loss_fn(net(tx[i])[:, 0], ty[i])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    return [(m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy()) for m in linears]


@dataclass
class SafeDaggerEpisodes:
    """One SafeDAgger rollout: DAgger's gated episode with the classifier as the gate, plus the
    diagnostic count of frames the learner drove while deviating by more than ``tau``."""

    classifier: DeviationClassifier
    tau: float
    parts: ActionParts

    def __call__(self, env: Any, actor: Any, seed: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        data, info = MixtureEpisodes(0.0, self.classifier, self.parts)(env, actor, seed)
        drove = ~data[LABEL_KEY].astype(bool)
        strayed = deviation(data["info.executed_action"][drove], data["action"][drove], self.parts, self.tau) > self.tau
        info["missed_deviations"] = int(strayed.sum())
        return data, info


@dataclass
class SafeDagger(Family):
    """SafeDAgger's rounds (module docstring). ``hidden``/``steps``: the classifier's MLP and its
    optimiser steps per round."""

    name: str = "safedagger"
    OPTIONS: ClassVar[tuple[str, ...]] = ("hidden", "steps")
    CHUNK_LABELS: ClassVar[bool] = False  # its own labelling: single-step labels
    FOREIGN: ClassVar[bool] = False  # its rollouts ask the task's own expert (not tried with a foreign one)
    hidden: tuple[int, ...] = (64, 64)
    steps: int = 1000
    last: dict[str, Any] = field(default_factory=dict)  # the latest classifier's fit, for the round's entry
    classifier: DeviationClassifier | None = None  # the latest classifier

    def episodes(self, run: Any, store: Any, env: Any, r: int, beta: float, gate: float | None) -> SafeDaggerEpisodes:
        if gate is None:
            raise DemoError("--gate", "SafeDAgger needs the deviation its classifier predicts: --gate deviation:TAU (rad)")
        data, bundle = run.data, run.bundle()
        parts = ActionParts.of(env)
        frames = frame_indices(data.ends, data.val_episodes)
        if data.labelled is not None:
            frames = frames[data.labelled[frames]]
        if len(frames) == 0:
            raise DemoError("--val-fraction", "SafeDAgger fits its classifier on held-out episodes: raise --val-fraction "
                                              "above 0 (e.g. 0.3)")
        y = deviation(learner_actions(bundle, data, frames), data.action[frames], parts, gate) > gate
        x = data.obs[frames]
        layers = fit_classifier(x, y, self.hidden, self.steps, seed=run.config.seed + 7919 * r)
        classifier = self.classifier = DeviationClassifier(layers, bundle.obs_spec, bundle.obs_norm.low, bundle.obs_norm.high)
        fired = classifier.logits(x) > 0
        self.last = {"classifier_frames": int(len(frames)), "classifier_positive_rate": float(y.mean()),
                     "classifier_accuracy": float((fired == y).mean()),
                     "classifier_recall": float(fired[y].mean()) if y.any() else None}
        return SafeDaggerEpisodes(classifier, gate, parts)

    def round_entry(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        return {"takeovers": int(sum(int(i.get("takeovers", 0)) for i in infos)),
                "missed_deviations": int(sum(int(i.get("missed_deviations", 0)) for i in infos)), **self.last}

    def to_json(self) -> dict[str, Any]:
        return {"classifier": {"hidden": list(self.hidden), "steps": self.steps}}
