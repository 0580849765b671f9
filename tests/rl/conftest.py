"""What the RL tests share."""

from __future__ import annotations

import numpy as np
import pytest

from demo.gym.env import DemoEnv


@pytest.fixture(scope="module")
def reach_sweep() -> list[dict[str, np.ndarray]]:
    """30 frames of ``reach`` (seed 5) while every joint sweeps slowly: states a policy reacts to."""
    env = DemoEnv("reach", store_layout=True, pos_tol=0.04, rot_tol=0.4)
    frame, _ = env.reset(seed=5)
    out = [frame]
    for t in range(29):
        frame, *_ = env.step(np.r_[frame["obs.joint_pos"] + 0.05 * np.sin(0.2 * t), 0.0].astype(np.float32))
        out.append(frame)
    env.close()
    return out
