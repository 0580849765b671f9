"""The policy registry: algorithms by name, options parsed by type, clear errors."""

from __future__ import annotations

import pytest
import torch

from demo.errors import DemoError
from demo.policies.mlp import MLPConfig, MLPPolicy
from demo.policies.policy import PolicySpec, build_policy, policy_class, policy_config


def test_bc_is_the_mlp_and_options_are_parsed_by_type() -> None:
    assert policy_class("bc") is MLPPolicy
    config = policy_config("bc", {"hidden": "64,32", "layer_norm": "true", "dropout": "0.1", "activation": "gelu"})
    assert config == MLPConfig(hidden=(64, 32), activation="gelu", layer_norm=True, dropout=0.1)
    policy = build_policy("bc", PolicySpec(obs_dim=5, action_dim=3, n_obs=2, horizon=4), config)
    out = policy.predict(torch.zeros(7, 2, 5))
    assert out.shape == (7, 4, 3)


def test_unknown_algorithm_or_option_fails_clearly() -> None:
    with pytest.raises(DemoError, match="unknown policy 'nope'"):
        policy_class("nope")
    with pytest.raises(DemoError, match="has no option 'widht'"):
        policy_config("bc", {"widht": "3"})
    with pytest.raises(DemoError, match="is not a valid tuple"):
        policy_config("bc", {"hidden": "a,b"})
    with pytest.raises(DemoError, match="activation"):
        policy_config("bc", {"activation": "tanhh"})


def test_mlp_loss_ignores_padded_chunk_steps() -> None:
    torch.manual_seed(0)
    policy = build_policy("bc", PolicySpec(obs_dim=2, action_dim=1, n_obs=1, horizon=3), {"hidden": (8,)})
    obs = torch.randn(4, 1, 2)
    target = policy(obs).detach().clone()
    pad = torch.zeros(4, 3, dtype=torch.bool)
    assert policy.loss(obs, target, pad).item() == pytest.approx(0.0, abs=1e-12)
    target[:, 2] += 100.0  # wrong only where padded
    pad[:, 2] = True
    assert policy.loss(obs, target, pad).item() == pytest.approx(0.0, abs=1e-12)
    pad[:, 2] = False
    assert policy.loss(obs, target, pad).item() > 1000
