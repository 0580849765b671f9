"""A bounded residual correction on top of a frozen policy (ResiP: Ankile et al. 2024).

The base policy (any imitation run: BC with chunks, diffusion, ACT) runs as it was trained, chunks and
temporal ensembling included; at every control step a small Gaussian policy reads the current state and
the base policy's action for it and adds a correction to that action:

    executed = base + bound * clip(mean(x), -1, 1),      x = [state vector, base action]

``bound`` is the largest correction per action entry, in the base policy's action units (rad for joint
targets, 0..1 for the gripper's closedness): a fraction (``scale``) of each entry's half-range in the
demonstrations the base was trained on, so that the residual can refine where the base hands the arm but
never take it somewhere else. The residual's last layer starts near zero: before RL has changed it, the
corrected policy is the base policy.

A run directory trained this way (:mod:`demo.rl.residual`) holds the base policy's record and weights
unchanged, and beside them the residual's record (``run.json``'s ``residual``) and tensors
(``residual.*`` and ``normalizer.residual_obs.*`` in ``policy.safetensors``); ``demo eval RUN`` executes
the base and the residual's mean through :class:`demo.policies.actor.PolicyActor`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from demo.policies.gaussian import GaussianConfig, GaussianPolicy
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import ObsSpec
from demo.policies.policy import PolicySpec

TENSORS = "residual."  # prefix of the residual's weights in policy.safetensors
NORMALIZER = "normalizer.residual_obs"  # ... and of its input normaliser


def residual_bound(action_norm: MinMaxNormalizer, scale: float) -> np.ndarray:
    """``[A]``: ``scale`` times each action entry's half-range in the base policy's training data."""
    return (scale * (action_norm.high - action_norm.low) / 2.0).astype(np.float32)


def residual_input(obs_spec: ObsSpec, frame: dict[str, np.ndarray], base: np.ndarray) -> np.ndarray:
    """A residual's raw input for one frame and the base policy's action for it: ``[state, base]`` (float32)."""
    return np.concatenate([obs_spec.vector(frame), np.asarray(base, np.float32)]).astype(np.float32)


@dataclass
class Residual:
    """The correction a residual policy adds to a base policy's action (module docstring)."""

    policy: GaussianPolicy  # normalised input -> normalised correction in [-1, 1] (its mean when executed)
    obs_spec: ObsSpec  # the state part of its input (one frame)
    obs_norm: MinMaxNormalizer  # over the whole input [state, base action]
    bound: np.ndarray  # [A] the largest correction per action entry, base policy's action units
    scale: float

    def normalized(self, x: np.ndarray) -> np.ndarray:
        return np.clip(self.obs_norm.normalize(x), -OBS_CLIP, OBS_CLIP).astype(np.float32)

    def correction(self, frame: dict[str, np.ndarray], base: np.ndarray) -> np.ndarray:
        """``[A]``: the mean correction for this frame (what evaluation executes)."""
        with torch.inference_mode():
            mean = self.policy.mean(torch.from_numpy(self.normalized(residual_input(self.obs_spec, frame, base))[None]))[0].numpy()
        return self.bound * np.clip(mean, -1.0, 1.0)

    def to_json(self) -> dict[str, Any]:
        return {"obs": self.obs_spec.to_json(), "hidden": list(self.policy.config.hidden),
                "init_log_std": float(self.policy.config.init_log_std), "scale": self.scale,
                "bound": [float(b) for b in self.bound]}

    def tensors(self) -> dict[str, torch.Tensor]:
        """What ``policy.safetensors`` holds of it besides the base policy's tensors."""
        out = {TENSORS + k: v.detach().cpu().contiguous().clone() for k, v in self.policy.state_dict().items()}
        out.update(self.obs_norm.state_dict(NORMALIZER))
        return out


def make_residual(obs_spec: ObsSpec, action_norm: MinMaxNormalizer, scale: float, hidden: tuple[int, ...],
                  init_log_std: float) -> Residual:
    """A fresh residual for a base policy with this action normaliser (identity normaliser of its input)."""
    dim = obs_spec.dim + action_norm.dim
    policy = GaussianPolicy(PolicySpec(dim, action_norm.dim), GaussianConfig(hidden, init_log_std))
    return Residual(policy, obs_spec, MinMaxNormalizer(-np.ones(dim), np.ones(dim)), residual_bound(action_norm, scale),
                    scale)


def load_residual(record: dict[str, Any], tensors: dict[str, torch.Tensor], action_dim: int) -> Residual:
    """The residual of a run record's ``residual`` section and its tensors; ValueError/KeyError when they
    disagree (the caller names the file)."""
    obs_spec = ObsSpec.from_json(record["obs"])
    if obs_spec.images:
        raise ValueError("a residual reads state, not camera images")
    bound = np.asarray(record["bound"], np.float32)
    if bound.shape != (action_dim,) or not np.isfinite(bound).all() or (bound < 0).any():
        raise ValueError(f"the residual's bound must be {action_dim} finite values >= 0")
    dim = obs_spec.dim + action_dim
    policy = GaussianPolicy(PolicySpec(dim, action_dim),
                            GaussianConfig(tuple(record["hidden"]), float(record.get("init_log_std", -1.0))))
    weights = {k[len(TENSORS):]: v for k, v in tensors.items() if k.startswith(TENSORS)}
    policy.load_state_dict(weights, strict=True)
    obs_norm = MinMaxNormalizer.from_state_dict(tensors, NORMALIZER)
    if obs_norm.dim != dim:
        raise ValueError(f"the residual's input normaliser has {obs_norm.dim} entries, its input {dim}")
    return Residual(policy.eval(), obs_spec, obs_norm, bound, float(record.get("scale", 0.0)))
