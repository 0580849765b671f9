"""Actions relative to the current observation: what the network predicts for absolute targets.

Absolute joint position targets move by ~0.02-0.05 rad per control step, while the joints range
over about a radian across a dataset: min-max normalised absolute targets leave the network a few
percent of its output range for what matters, and a 1% error is a whole step's motion, which
compounds into flailing within a few steps. So for an action representation with absolute targets
of an observed quantity, the network predicts ``action - base(obs_t)`` for every step of the chunk
(all relative to the *query* frame ``t``, as in UMI's relative trajectories), and the actor adds
the base back. The store keeps absolute actions; this is only the network's parameterisation,
recorded in the run.

Default: ``joint_pos`` actions whose first ``n`` entries are the targets of ``obs.joint_pos``
(``n`` its size) are relative on those entries; the gripper and every other representation stay
absolute. ``--absolute-actions`` turns it off.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.store import FeatureSpec, StoreMeta


@dataclass(frozen=True)
class RelativeActions:
    """``action[action_dims] -= obs[obs_key][obs_dims]`` of the query frame."""

    obs_key: str
    obs_dims: tuple[int, ...]
    action_dims: tuple[int, ...]

    def base(self, frames: Mapping[str, np.ndarray], action_dim: int) -> np.ndarray:
        """Per frame ``[N, action_dim]``: the values to subtract (zero on absolute dims)."""
        obs = np.asarray(frames[self.obs_key], dtype=np.float32)
        out = np.zeros((len(obs), action_dim), dtype=np.float32)
        out[:, list(self.action_dims)] = obs.reshape(len(obs), -1)[:, list(self.obs_dims)]
        return out

    def base_frame(self, frame: Mapping[str, np.ndarray], action_dim: int) -> np.ndarray:
        out = np.zeros(action_dim, dtype=np.float32)
        out[list(self.action_dims)] = np.asarray(frame[self.obs_key], dtype=np.float32).reshape(-1)[list(self.obs_dims)]
        return out

    def to_json(self) -> dict[str, Any]:
        return {"obs_key": self.obs_key, "obs_dims": list(self.obs_dims), "action_dims": list(self.action_dims)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any] | None) -> "RelativeActions | None":
        if not d:
            return None
        return cls(str(d["obs_key"]), tuple(int(i) for i in d["obs_dims"]), tuple(int(i) for i in d["action_dims"]))


def default_relative(meta: StoreMeta) -> RelativeActions | None:
    """Joint position targets relative to the measured joint positions, when the store has both."""
    spec: FeatureSpec | None = meta.features.get("obs.joint_pos")
    if meta.action.name != "joint_pos" or spec is None or len(spec.shape) != 1:
        return None
    n = spec.shape[0]
    if n > meta.action.dim:
        return None
    return RelativeActions("obs.joint_pos", tuple(range(n)), tuple(range(n)))
