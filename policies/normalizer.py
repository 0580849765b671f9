"""Min-max normalisation of observations and actions to [-1, 1], stored with the policy.

Per dimension, ``x_norm = (x - min) / (max - min) * 2 - 1`` with the min and max of the training
data (Diffusion Policy's ``LinearNormalizer`` in "limits" mode). A dimension that barely varies in
the data (an idle gripper's closedness jitters by ~1e-4, an object that never moves) would get an
enormous scale, and the slightest deviation in a rollout would become a huge input: the network's
output explodes (we saw targets 50 rad off within three steps). So :meth:`fit` widens every range to
at least ``min_span`` (default 0.01 in the data's units: rad, m, closedness), centred on its
midpoint; such a dimension maps into a small band around 0.

Values outside the training range map outside [-1, 1]; nothing is clipped, because a learner's own
states (DAgger) legitimately leave the range of the demonstrations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

MIN_SPAN = 1e-2
# Normalised observations are clipped to +-OBS_CLIP (training windows and rollouts alike): a state far
# outside the data (a knocked-over cube: a 6D-rotation entry that was constant moves by 1, i.e. 100
# half-ranges) would otherwise dominate every activation of the network.
OBS_CLIP = 5.0


@dataclass
class MinMaxNormalizer:
    """Per-dimension affine map to [-1, 1]; ``low``/``high`` are float32 arrays of the data's units."""

    low: np.ndarray
    high: np.ndarray

    def __post_init__(self) -> None:
        self.low = np.asarray(self.low, dtype=np.float32).reshape(-1)
        self.high = np.asarray(self.high, dtype=np.float32).reshape(-1)
        if self.low.shape != self.high.shape:
            raise ValueError(f"low {self.low.shape} and high {self.high.shape} differ in shape")
        span = self.high - self.low
        if (span <= 0).any():
            raise ValueError("every dimension needs high > low (use fit(), which widens narrow ranges)")
        # x_norm = x * scale + offset
        self.scale = (2.0 / span).astype(np.float32)
        self.offset = (-1.0 - self.low * self.scale).astype(np.float32)
        self._torch: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}

    @classmethod
    def fit(cls, x: np.ndarray, min_span: float = MIN_SPAN) -> "MinMaxNormalizer":
        """From data ``[N, dim]`` (any leading shape; the last axis is the dimension)."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, np.shape(x)[-1])
        if len(x) == 0:
            raise ValueError("cannot fit a normaliser to no data")
        return cls.from_limits(x.min(axis=0), x.max(axis=0), min_span)

    @classmethod
    def from_limits(cls, low: np.ndarray, high: np.ndarray, min_span: float = MIN_SPAN) -> "MinMaxNormalizer":
        """From per-dimension limits, each range widened to at least ``min_span`` about its middle."""
        low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
        mid, half = (low + high) / 2, np.maximum(high - low, min_span) / 2
        return cls(mid - half, mid + half)

    @property
    def dim(self) -> int:
        return int(self.low.shape[0])

    def normalize(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, dtype=np.float32) * self.scale + self.offset).astype(np.float32, copy=False)

    def unnormalize(self, y: np.ndarray) -> np.ndarray:
        return ((np.asarray(y, dtype=np.float32) - self.offset) / self.scale).astype(np.float32, copy=False)

    def _tensors(self, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor]:
        key = str(device)
        if key not in self._torch:
            self._torch[key] = (torch.from_numpy(self.scale).to(device), torch.from_numpy(self.offset).to(device))
        return self._torch[key]

    def normalize_t(self, x: torch.Tensor) -> torch.Tensor:
        scale, offset = self._tensors(x.device)
        return x * scale + offset

    def unnormalize_t(self, y: torch.Tensor) -> torch.Tensor:
        scale, offset = self._tensors(y.device)
        return (y - offset) / scale

    def state_dict(self, prefix: str) -> dict[str, torch.Tensor]:
        return {f"{prefix}.low": torch.from_numpy(self.low.copy()), f"{prefix}.high": torch.from_numpy(self.high.copy())}

    @classmethod
    def from_state_dict(cls, tensors: dict[str, torch.Tensor], prefix: str) -> "MinMaxNormalizer":
        try:
            return cls(tensors[f"{prefix}.low"].numpy(), tensors[f"{prefix}.high"].numpy())
        except KeyError as exc:
            raise KeyError(f"normaliser tensor {exc.args[0]!r} missing") from None
