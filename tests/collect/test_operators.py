"""Operator profiles: idle starts, jitter, pauses and failures appear as their profile says."""

from __future__ import annotations

import numpy as np
import pytest

from demo.collect.operators import PROFILES, Operator, get_profile
from demo.errors import DemoError


def drive(profile: str, seed: int, steps: int = 200) -> tuple[Operator, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    op = Operator(PROFILES[profile], rng, fps=20.0, horizon=steps, n_arm=7)
    clean = np.stack([np.r_[np.full(7, 0.01 * t), 1.0] for t in range(steps)]).astype(np.float32)
    sent = []
    hold = np.zeros(8, np.float32)
    for t in range(steps):
        cmd = op.command(t, clean[t], hold)
        sent.append(cmd)
        hold = cmd
    return op, clean, np.stack(sent)


def test_expert_sends_the_clean_command() -> None:
    _, clean, sent = drive("expert", 0)
    np.testing.assert_array_equal(sent, clean)


def test_poor_operator_idles_at_the_start_and_jitters() -> None:
    for seed in range(5):
        op, clean, sent = drive("poor", seed)
        assert op.idle_steps >= 20  # at least 1 s at 20 Hz
        assert np.all(sent[: op.idle_steps] == 0)
        moving = np.flatnonzero(np.abs(np.diff(sent[:, :7], axis=0)).sum(1) > 0)
        second_diff = np.abs(np.diff(sent[moving[0] : moving[0] + 40, :7], n=2, axis=0)).mean()
        assert second_diff > np.abs(np.diff(clean[:, :7], n=2, axis=0)).mean() + 0.01


def test_failure_rates_follow_the_profiles() -> None:
    rng = np.random.default_rng(0)
    rates = {
        name: np.mean([Operator(p, rng, 20.0, 200, 7).fails for _ in range(2000)]) for name, p in PROFILES.items()
    }
    assert rates["expert"] == 0
    assert rates["good"] < rates["okay"] < rates["poor"]
    assert abs(rates["poor"] - PROFILES["poor"].failure_prob) < 0.05


def test_drop_failure_opens_the_gripper() -> None:
    for seed in range(200):
        op, _, sent = drive("poor", seed)
        if op.failure_kind == "drop":
            assert np.all(sent[op.failure_step :, 7] == 0.0)
            return
    pytest.fail("no drop failure in 200 seeds")


def test_unknown_profile_is_a_clear_error() -> None:
    with pytest.raises(DemoError, match="unknown operator profile 'bad'"):
        get_profile("bad")
