"""The token transformer (``--algo transformer``): from cameras, training hides the joints as ACT's does."""

from __future__ import annotations

import pytest
import torch

from demo.errors import DemoError
from demo.policies.instruction import TEXT_PAD, TEXT_TOKENS
from demo.policies.policy import PolicySpec, build_policy
from demo.policies.transformer import object_columns

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


def test_objects_make_one_token_each() -> None:
    # the joints (2 values), three objects' positions (a (3, 3) key), the arm's speed (1), the objects' colours (a
    # (3, 2) key), then a camera (4 features): tokens per frame, the arm's values together, each object's row of
    # both object keys, the camera
    spec = PolicySpec(obs_dim=22, action_dim=3, n_obs=2, horizon=4, obs_layout=((1, 2), (3, 3), (1, 1), (3, 2)),
                      token_dims=(18, 4))
    assert [c.tolist() for c in object_columns(spec.obs_layout)] == [
        [[0, 1, 11]], [[2, 3, 4, 12, 13], [5, 6, 7, 14, 15], [8, 9, 10, 16, 17]]]
    torch.manual_seed(0)
    policy = build_policy("transformer", spec, {**TINY, "state_tokens": "objects"}).eval()
    obs = torch.randn(5, 2, 22)
    tokens, _ = policy.tokens(obs)
    assert tokens.shape == (5, 2 * (1 + 3 + 1), 16)
    moved = obs.clone()
    moved[:, :, 14] += 1.0  # the second object's colour only
    changed = (policy.tokens(moved)[0] - tokens).abs().amax(dim=(0, 2)) > 1e-6
    assert changed.tolist() == [False, False, True, False, False] * 2
    # training's state dropout hides every state token of a hidden sample, never the camera's
    pad = policy.tokens(obs, torch.tensor([True, False, False, False, False]))[1]
    assert pad[0].tolist() == [True, True, True, True, False] * 2 and not pad[1:].any()
    # the one-token default keeps the weights' names and shapes of runs trained before objects existed
    frame = build_policy("transformer", spec, TINY)
    assert [tuple(m.weight.shape) for m in frame.frame_in] == [(16, 18), (16, 4)] and frame.kind.shape == (3, 16)
    assert "columns0" not in frame.state_dict()
    assert policy(obs).shape == (5, 4, 3)
    with pytest.raises(DemoError, match="state_tokens"):
        build_policy("transformer", spec, {"state_tokens": "rows"})
    with pytest.raises(ValueError, match="layout"):  # a spec without the layout (a run trained before it)
        build_policy("transformer", PolicySpec(obs_dim=11, action_dim=3), {**TINY, "state_tokens": "objects"})


def test_the_layout_is_recorded_by_key() -> None:
    spec = PolicySpec(obs_dim=11, action_dim=3, obs_layout=((1, 2), (3, 3)))
    assert spec.to_json()["obs_layout"] == [[1, 2], [3, 3]] and PolicySpec.from_json(spec.to_json()) == spec
    assert "obs_layout" not in PolicySpec(obs_dim=11, action_dim=3).to_json()  # runs before it read as before
