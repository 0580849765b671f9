"""Executing a policy: observation history, receding-horizon chunks, ACT temporal ensembling."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from demo.policies.actor import ExecConfig, PolicyActor
from demo.policies.normalizer import MinMaxNormalizer
from demo.policies.observation import ObsSpec
from demo.policies.policy import Policy, PolicySpec
from demo.policies.relative import RelativeActions


class Ramp(Policy):
    """Chunk step k = (last observation) + 10 * k, plus the first history entry in dim 1."""

    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        k = torch.arange(self.spec.horizon, dtype=obs.dtype)[None, :, None]
        out = obs[:, -1:, :1] + 10 * k
        return torch.cat([out, obs[:, :1, :1].expand_as(out)], dim=-1)


def make_actor(horizon: int, execution: ExecConfig, n_obs: int = 1, relative: RelativeActions | None = None) -> PolicyActor:
    policy = Ramp(PolicySpec(obs_dim=1, action_dim=2, n_obs=n_obs, horizon=horizon), None)
    identity = MinMaxNormalizer(np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    # Observations 0..9 normalise to 0..0.9 (x / 10), inside the clip range.
    return PolicyActor(policy, ObsSpec(("obs.x",), (1,)), MinMaxNormalizer(np.array([-10.0]), np.array([10.0])),
                       identity, execution, relative=relative)


def run(actor: PolicyActor, steps: int, scale: float = 1.0) -> np.ndarray:
    actor.reset(0)
    return np.array([actor.act({"obs.x": np.array([float(t) * scale])}) for t in range(steps)])


def test_single_step_policy_follows_the_observation() -> None:
    actions = run(make_actor(1, ExecConfig(1, None)), 5)
    assert np.allclose(actions[:, 0], [0, 0.1, 0.2, 0.3, 0.4])


def test_receding_horizon_executes_k_steps_per_query() -> None:
    actor = make_actor(4, ExecConfig(execute=3, ensemble=None))
    actions = run(actor, 7)
    # Queries at t = 0, 3, 6; step t executes chunk[t - query] = query / 10 + 10 (t - query).
    assert np.allclose(actions[:, 0], [0, 10, 20, 0.3, 10.3, 20.3, 0.6])
    assert actor.queries == 3


def test_temporal_ensembling_weights_older_chunks_first() -> None:
    m = 0.5
    actor = make_actor(3, ExecConfig(execute=1, ensemble=m))
    actions = run(actor, 4)
    # At t = 2 the chunks from t = 0, 1, 2 predict 0 + 20, 0.1 + 10, 0.2 + 0; weights exp(-m i), oldest i = 0.
    w = np.exp(-m * np.arange(3))
    assert actions[2, 0] == pytest.approx(float((w * [20, 10.1, 0.2]).sum() / w.sum()), rel=1e-6)
    # At t = 3 the chunk from t = 0 has expired.
    assert actions[3, 0] == pytest.approx(float((w * [20.1, 10.2, 0.3]).sum() / w.sum()), rel=1e-6)
    assert actor.queries == 4


def test_history_repeats_the_first_frame_at_the_start() -> None:
    actions = run(make_actor(1, ExecConfig(1, None), n_obs=3), 5)
    # Dim 1 echoes the oldest history entry: frame 0 until the history is full, then t - 2.
    assert np.allclose(actions[:, 1], [0, 0, 0, 0.1, 0.2])


def test_relative_actions_add_the_query_frame_base() -> None:
    relative = RelativeActions("obs.x", (0,), (1,))
    actor = make_actor(2, ExecConfig(execute=2, ensemble=None), relative=relative)
    actions = run(actor, 4)
    # Dim 1 (normalised obs) + base (the query frame's raw obs.x): queries at t = 0, 2.
    assert np.allclose(actions[:, 1], [0, 0, 2.2, 2.2])


def test_far_out_observations_are_clipped() -> None:
    actions = run(make_actor(1, ExecConfig(1, None)), 2, scale=1000.0)
    assert np.allclose(actions[:, 0], [0, 5])  # 1000 / 10 = 100 half-ranges, clipped to OBS_CLIP


def test_execution_is_checked_against_the_chunk() -> None:
    with pytest.raises(ValueError):
        make_actor(2, ExecConfig(execute=3))


def test_binary_dims_are_executed_open_or_closed() -> None:
    """ExecConfig.binary snaps those dims at 0.5 (a gripper), leaves the others, and survives JSON."""
    execution = ExecConfig(1, None, binary=(0,))
    actions = run(make_actor(1, execution), 8)  # dim 0 follows x / 10: 0, 0.1, ..., 0.7
    assert actions[:, 0].tolist() == [0, 0, 0, 0, 0, 1, 1, 1]
    assert np.allclose(actions[:, 1], np.arange(8) / 10)  # not a binary dim: as predicted
    assert ExecConfig.from_json(execution.to_json()) == execution
    assert ExecConfig.from_json({"execute": 2}).binary == ()  # runs recorded before the option


class TwoModes(Policy):
    """A chunk that is all +0.5 or all -0.5, each row's sign drawn from the generator (a bimodal policy)."""

    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        sign = torch.randint(0, 2, (obs.shape[0], 1, 1), generator=generator).float() * 2 - 1
        return 0.5 * sign.expand(obs.shape[0], self.spec.horizon, self.spec.action_dim).clone()


@pytest.mark.parametrize("candidates", [1, 8])
def test_coherent_sampling_keeps_the_mode_it_chose(candidates: int) -> None:
    policy = TwoModes(PolicySpec(obs_dim=1, action_dim=1, n_obs=1, horizon=4), None)
    identity = MinMaxNormalizer(np.array([-1.0]), np.array([1.0]))
    actor = PolicyActor(policy, ObsSpec(("obs.x",), (1,)), identity, identity,
                        ExecConfig(execute=1, ensemble=None, candidates=candidates))
    signs = np.sign(run(actor, 40)[:, 0])
    if candidates == 1:
        assert len(set(signs)) == 2  # a fresh draw each step switches modes
    else:
        assert (signs == signs[0]).all()  # every later draw of 8 holds one chunk of the first mode
    assert actor.queries == 40
    again = np.sign(run(actor, 40)[:, 0])
    assert (again == signs).all()  # the same episode seed, the same draws


def test_candidates_are_checked_and_recorded() -> None:
    with pytest.raises(ValueError, match="candidates"):
        ExecConfig(candidates=0).check(4)
    assert ExecConfig.from_json(ExecConfig(candidates=8).to_json()).candidates == 8
    assert "candidates" not in ExecConfig().to_json()  # runs without it read and write as before
