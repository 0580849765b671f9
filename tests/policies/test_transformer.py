"""The token transformer (``--algo transformer``): from cameras, training hides the joints as ACT's does."""

from __future__ import annotations

import pytest
import torch

from demo.errors import DemoError
from demo.policies.instruction import TEXT_PAD, TEXT_TOKENS
from demo.policies.policy import PolicySpec, build_policy

TINY = {"d_model": 16, "heads": 2, "layers": 1, "feedforward": 32, "dropout": 0.0}


def test_from_cameras_training_hides_the_joints_from_attention() -> None:
    spec = PolicySpec(obs_dim=5, action_dim=3, n_obs=2, horizon=6, token_dims=(2, 3))  # joints (2), a camera (3)
    torch.manual_seed(0)
    policy = build_policy("transformer", spec, TINY).eval()
    obs = torch.randn(8, 2, 5)
    other_joints, other_camera = obs.clone(), obs.clone()
    other_joints[..., :2] += 1.0
    other_camera[..., 2:] += 1.0
    hidden = torch.ones(8, dtype=torch.bool)
    # joints hidden: the chunk no longer depends on them, and still on the camera; in view, on both
    assert torch.allclose(policy(obs, hidden), policy(other_joints, hidden), atol=1e-6)
    assert not torch.allclose(policy(obs, hidden), policy(other_camera, hidden), atol=1e-3)
    assert not torch.allclose(policy(obs), policy(other_joints), atol=1e-3)
    # training draws which samples to hide (none at 0: the same loss as the plain forward pass's)
    action, pad = torch.randn(8, 6, 3), torch.zeros(8, 6, dtype=torch.bool)
    never = build_policy("transformer", spec, {**TINY, "state_dropout": 0.0}).train()
    never.load_state_dict(policy.state_dict())
    plain = ((never(obs) - action).abs()).mean().item()  # the chunk's L1, the default
    assert never.loss(obs, action, pad).item() == pytest.approx(plain, rel=1e-6)
    torch.manual_seed(1)
    assert policy.train().loss(obs, action, pad).item() != pytest.approx(plain, rel=1e-6)
    # without cameras nothing is hidden, whatever the setting
    state_only = build_policy("transformer", PolicySpec(obs_dim=5, action_dim=3, n_obs=2, horizon=6), TINY).train()
    assert state_only.loss(obs, action, pad).item() == pytest.approx(
        ((state_only(obs) - action).abs()).mean().item(), rel=1e-6)
    squared = build_policy("transformer", spec, {**TINY, "state_dropout": 0.0, "loss": "mse"}).train()
    squared.load_state_dict(policy.state_dict())
    assert squared.loss(obs, action, pad).item() == pytest.approx(((squared(obs) - action).square()).mean().item(),
                                                                  rel=1e-6)
    with pytest.raises(DemoError, match="loss"):
        build_policy("transformer", spec, {"loss": "huber"})
    with pytest.raises(DemoError, match="state_dropout"):
        build_policy("transformer", spec, {"state_dropout": 1.0})


def test_hidden_joints_and_padded_words_share_one_mask() -> None:
    spec = PolicySpec(obs_dim=5, action_dim=3, n_obs=1, horizon=4, token_dims=(2, 3), text_dim=4)
    policy = build_policy("transformer", spec, TINY).eval()
    words = torch.randn(2, 3, 4)
    obs = {"state": torch.randn(2, 1, 5), TEXT_TOKENS: words, TEXT_PAD: torch.tensor([[False, False, True]] * 2)}
    tokens, pad = policy.tokens(obs, torch.tensor([True, False]))
    assert tokens.shape == (2, 2 + 3, 16)
    assert pad.tolist() == [[True, False, False, False, True], [False, False, False, False, True]]
    assert policy.tokens(obs)[1].tolist() == [[False, False, False, False, True]] * 2
