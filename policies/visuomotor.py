"""Visuomotor policies: image encoders and proprioception in front of any registered policy.

A :class:`VisuomotorPolicy` wraps a policy class (BC's MLP, diffusion, ...) built for a vector
observation. Each camera has its own encoder (:class:`demo.policies.encoders.CameraEncoder`: random
crop in training, centre crop in evaluation, a backbone, spatial-softmax keypoints, a linear layer);
its features are concatenated with the normalised low-dim vector (the robot's proprioception by
default) frame by frame, and the wrapped policy sees ``[B, n_obs, obs_dim + cameras * features]``.
Encoders and policy train end to end on the wrapped policy's own loss, as in Diffusion Policy.

With an auxiliary target (``spec.aux_dim`` > 0; ``demo train --aux-target obs.object_pos``) a linear layer
also predicts a state the policy is not given, e.g. the objects' positions, from the current frame's camera
features, and training adds its mean squared error (the state normalised to [-1, 1], weighted by the
encoder's ``aux_weight``) to the action loss: the encoders are told where to look, not only through the
actions (privileged-state prediction, as in asymmetric sim-to-real training). The state arrives under
:data:`AUX_TARGET` in training batches only; validation, rollouts and the server never read it.

Observations reach it as a dict (:data:`STATE` -> ``[B, n_obs, obs_dim]`` float, and per camera key
``[B, n_obs, H, W, 3]`` uint8), built by :class:`demo.training.data.Windows` in training and by
:class:`demo.policies.actor.PolicyActor` in rollouts.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from demo.policies.encoders import CameraEncoder, EncoderConfig
from demo.policies.instruction import CONDITION, TEXT_PAD, TEXT_TOKENS
from demo.policies.observation import STATE, IMAGE_PREFIX
from demo.policies.policy import Policy, PolicySpec

AUX_TARGET = "aux_target"  # a training batch's [B, aux_dim] normalised auxiliary state (the query frame's)


def encoder_config(encoder: EncoderConfig | dict[str, Any] | None) -> EncoderConfig:
    if isinstance(encoder, EncoderConfig):
        return encoder
    fields = {f.name for f in dataclasses.fields(EncoderConfig)}
    unknown = sorted(set(encoder or {}) - fields)
    if unknown:
        raise ValueError(f"encoder has no option {', '.join(unknown)} (options: {', '.join(sorted(fields))})")
    return EncoderConfig(**(encoder or {}))


class VisuomotorPolicy(Policy):
    """Per-camera encoders + the low-dim vector -> the wrapped policy class ``head``."""

    def __init__(self, spec: PolicySpec, config: Any, head: type[Policy], encoder: EncoderConfig):
        super().__init__(spec, config)
        self.name = head.name
        self.encoder_config = encoder
        self.keys = [key for key, _, _ in spec.images]
        # Given a condition (spec.cond_dim > 0: an instruction's, the observation's CONDITION), the encoders FiLM
        # their feature maps by it (spec.film_cameras), and a head that takes one its hidden layers (spec.film_head)
        self.cameras = nn.ModuleDict({key[len(IMAGE_PREFIX):]: CameraEncoder(h, w, encoder, spec.cond_dim if spec.film_cameras else 0)
                                      for key, h, w in spec.images})
        self.head_condition = bool(spec.cond_dim) and spec.film_head and head.takes_condition
        self.aux = nn.Linear(len(self.keys) * encoder.features, spec.aux_dim) if spec.aux_dim else None
        head_spec = dataclasses.replace(spec, obs_dim=spec.obs_dim + len(self.keys) * encoder.features, images=(), aux_dim=0,
                                        cond_dim=spec.cond_dim if self.head_condition else 0,
                                        token_dims=(spec.obs_dim, *[encoder.features] * len(self.keys)))
        self.head = head(head_spec, config)

    def encode(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """``{state, camera keys[, condition]}`` -> ``[B, n_obs, obs_dim + cameras * features]``."""
        return self.fuse(obs[STATE], self.preprocess(obs), obs.get(CONDITION))

    def preprocess(self, obs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Each camera's uint8 images as its backbone takes them: ``[B * n_obs, 3, ch, cw]`` floats,
        scaled and cropped (randomly in training)."""
        return {key: encoder.preprocess(obs[key].flatten(0, 1)) for key, encoder in zip(self.keys, self.cameras.values())}

    def fuse(self, state: torch.Tensor, crops: dict[str, torch.Tensor], condition: torch.Tensor | None = None
             ) -> torch.Tensor:
        """``state [B, n_obs, D]``, :meth:`preprocess`'s crops (and ``[B, cond_dim]`` conditions, the same for
        every frame of a sample) -> the wrapped policy's observation."""
        b, t = state.shape[:2]
        per_frame = None if condition is None else condition[:, None].expand(b, t, -1).reshape(b * t, -1)
        parts = [encoder.features(crops[key], per_frame).reshape(b, t, -1).to(state.dtype)
                 for key, encoder in zip(self.keys, self.cameras.values())]
        return torch.cat([state, *parts], dim=-1)

    def head_input(self, obs: dict[str, torch.Tensor], fused: torch.Tensor | None = None
                   ) -> torch.Tensor | dict[str, torch.Tensor]:
        """What the wrapped policy reads: :meth:`encode`'s vector (``fused``, when the caller has it), with an
        instruction's tokens beside it when the wrapped policy reads tokens (:mod:`demo.policies.instruction`)."""
        fused = self.encode(obs) if fused is None else fused
        if TEXT_TOKENS in obs:
            return {STATE: fused, TEXT_TOKENS: obs[TEXT_TOKENS], TEXT_PAD: obs[TEXT_PAD]}
        if self.head_condition:
            return {STATE: fused, CONDITION: obs[CONDITION]}
        return fused

    def loss(self, obs: dict[str, torch.Tensor], action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        """The wrapped policy's loss; in training with an auxiliary target, plus its weighted error (so validation
        losses stay the actions' alone, comparable with runs without one)."""
        fused = self.encode(obs)
        loss = self.head.loss(self.head_input(obs, fused), action, action_pad)
        if self.aux is not None and self.training and AUX_TARGET in obs:
            loss = loss + self.encoder_config.aux_weight * self.aux_error(fused, obs[AUX_TARGET])
        return loss

    def aux_error(self, fused: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Mean squared error of the auxiliary state predicted from the last frame's camera features of ``fused``
        (:meth:`encode`'s ``[B, n_obs, obs_dim + cameras * features]``) against ``target [B, aux_dim]``."""
        predicted = self.aux(fused[:, -1, self.spec.obs_dim:])
        return F.mse_loss(predicted.float(), target.float())

    @torch.no_grad()
    def predict(self, obs: dict[str, torch.Tensor], generator: torch.Generator | None = None) -> torch.Tensor:
        return self.head.predict(self.head_input(obs), generator=generator)


def encoder_record(policy: Policy) -> dict[str, Any] | None:
    """The encoder settings run.json records for a visuomotor policy (None for a state policy)."""
    return dataclasses.asdict(policy.encoder_config) if isinstance(policy, VisuomotorPolicy) else None
