"""Where training defaults come from: what is given, then the policy's measured best, then the loop's."""

from __future__ import annotations

import pytest

from demo.errors import DemoError
from demo.training.config import LOOP_DEFAULTS, POLICY_DEFAULTS, TrainConfig, for_policy


def test_given_values_win_then_the_policys_then_the_loops() -> None:
    c = for_policy("diffusion", steps=10, lr=None)
    assert c.steps == 10  # given
    assert c.chunk == 16 and c.n_obs == 2 and c.execute == 4 and c.ensemble is False  # diffusion's own
    assert c.lr == POLICY_DEFAULTS["diffusion"]["lr"]  # None means "not given"
    assert c.grad_clip == TrainConfig().grad_clip
    bc = for_policy("bc")
    assert bc.chunk == 16 and bc.ensemble is True and bc.n_obs == LOOP_DEFAULTS["n_obs"]


def test_a_bare_config_resolves_like_for_policy() -> None:
    assert TrainConfig(algo="diffusion", data="d", seed=3).resolved() == for_policy("diffusion", data="d", seed=3)
    with pytest.raises(ValueError, match="not resolved"):
        TrainConfig(algo="bc").check()


def test_a_shorter_chunk_shortens_execution_unless_given() -> None:
    assert for_policy("diffusion", chunk=2).execute == 2
    with pytest.raises(DemoError, match="--execute"):
        for_policy("diffusion", chunk=2, execute=3).check()


def test_unknown_policies_and_fields_are_refused() -> None:
    with pytest.raises(DemoError, match="unknown policy 'perceiver'"):
        for_policy("perceiver")
    with pytest.raises(TypeError, match="no field chunks"):
        for_policy("bc", chunks=4)


def test_dagger_learners_are_bcs_chunked_policy() -> None:
    from demo.imitation.dagger import learner_config

    c, bc = learner_config(steps=5), for_policy("bc")
    assert (c.chunk, c.ensemble) == (bc.chunk, bc.ensemble) == (16, True) and c.steps == 5
    assert learner_config(chunk=8).chunk == 8
