"""Chunks that continue a committed prefix (demo.policies.prefix): what the policy is told, what its loss
skips, how a run records it, and how the actor hands a client's committed actions to it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.cli.main import main
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.imitation.bc import train
from demo.policies import checkpoint as ckpt
from demo.policies.policy import PolicySpec, build_policy
from demo.policies.prefix import PREFIX, PREFIX_STEPS, CommittedPrefixPolicy
from demo.sim import make_env
from demo.training.config import TrainConfig


def test_the_loss_skips_exactly_the_steps_the_policy_was_told() -> None:
    """Each window draws how many of its first actions are given; the flags appended to the observation and the
    steps the loss skips are the same ones, and the given actions are the window's own."""
    torch.manual_seed(0)
    spec = PolicySpec(obs_dim=5, action_dim=2, horizon=6, prefix=3)
    policy = build_policy("bc", spec, {"hidden": (16,)})
    assert isinstance(policy, CommittedPrefixPolicy) and policy.inner.spec.obs_dim == 5 + 3 * (2 + 1)
    seen = {}

    def record(obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        seen.update(obs=obs, pad=action_pad)
        return obs.sum() * 0

    policy.inner.loss = record  # what the wrapped policy is asked to fit
    obs, action = torch.randn(64, 1, 5), torch.randn(64, 6, 2)
    ended = torch.zeros(64, 6, dtype=torch.bool)
    ended[:, 5] = True  # a window past its episode's end keeps that padding too
    policy.loss(obs, action, ended)
    extra = seen["obs"][:, 0, 5:]
    given = extra[:, 6:].bool()  # [B, 3] flags
    steps = given.sum(dim=1)
    assert set(steps.tolist()) == {0, 1, 2, 3}  # every d in 0 .. P is drawn
    assert torch.equal(given, torch.arange(3)[None] < steps[:, None])  # a prefix, never holes
    told = extra[:, :6].reshape(64, 3, 2)
    torch.testing.assert_close(told, action[:, :3] * given[..., None])  # the window's first actions, zero past d
    expected_pad = (torch.arange(6)[None] < steps[:, None]) | ended
    assert torch.equal(seen["pad"], expected_pad)


def test_without_a_prefix_the_policy_is_told_none() -> None:
    torch.manual_seed(0)
    policy = build_policy("bc", PolicySpec(obs_dim=4, action_dim=2, horizon=5, prefix=2), {"hidden": (16,)}).eval()
    obs = torch.randn(3, 1, 4)
    plain = policy.predict(obs)
    noise = torch.randn(3, 2, 2)
    told_zero = policy.predict({"state": obs, PREFIX: noise, PREFIX_STEPS: torch.zeros(3, dtype=torch.long)})
    torch.testing.assert_close(plain, told_zero)  # d = 0: whatever sits in the prefix is masked out
    told_two = policy.predict({"state": obs, PREFIX: noise, PREFIX_STEPS: torch.full((3,), 2)})
    assert not torch.allclose(plain, told_two)
    with pytest.raises(ValueError, match="prefix < chunk"):
        build_policy("bc", PolicySpec(obs_dim=4, action_dim=2, horizon=2, prefix=2))


@pytest.fixture(scope="module")
def prefix_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("prefix")
    collect_scripted(CollectConfig(task="pick", episodes=12, seed=0), root / "pick.zarr", workers=0)
    train(TrainConfig(data=str(root / "pick.zarr"), out=str(root / "run"), steps=600, prefix_steps=4))
    return root / "run"


def test_a_run_records_its_prefix_and_the_actor_continues_a_clients_actions(prefix_run: Path) -> None:
    record = json.loads((prefix_run / ckpt.RUN_FILE).read_text())["policy"]
    assert record["spec"]["prefix"] == 4 and record["spec"]["horizon"] == 16
    bundle = ckpt.load_bundle(prefix_run)
    assert isinstance(bundle.policy, CommittedPrefixPolicy)
    env = make_env("pick")
    frame = env.reset(5)
    env.close()
    actor = bundle.actor()
    actor.reset(0)
    plain = actor.chunk(frame)
    actor.reset(0)
    assert np.array_equal(actor.chunk(frame, np.zeros((0, 8), np.float32)), plain)  # nothing committed
    committed = (plain[:6] + np.r_[[0.05] * 7, 0.0]).astype(np.float32)  # the robot's plan differs from what the policy would do
    actor.reset(0)
    continued = actor.chunk(frame, committed)
    np.testing.assert_array_equal(continued[:4], committed[:4])  # only spec.prefix = 4 of the 6 are taken
    assert np.abs(continued[4:] - plain[4:]).max() > 1e-3  # and the rest follows from them
    actor.reset(0)
    with pytest.raises(ValueError, match="action dims"):
        actor.chunk(frame, np.zeros((2, 3), np.float32))
    # A policy without a prefix ignores one (a client may always send it).
    plain_run = ckpt.load_bundle(prefix_run).run  # the record without the prefix builds the ordinary policy
    spec = dict(plain_run["policy"]["spec"], prefix=0)
    assert not isinstance(build_policy("bc", PolicySpec.from_json(spec)), CommittedPrefixPolicy)


def test_a_prefix_as_long_as_the_chunk_is_refused(prefix_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    store = prefix_run.parent / "pick.zarr"
    assert main(["train", str(store), "--chunk", "4", "--prefix-steps", "4", "--out", str(prefix_run.parent / "bad")]) != 0
    err = capsys.readouterr().err.strip()
    assert "--prefix-steps" in err and "[0, --chunk=4)" in err and len(err.splitlines()) == 1
    assert not (prefix_run.parent / "bad").exists()


@pytest.mark.parametrize("algo", ["act", "diffusion", "transformer"])
def test_every_policy_takes_a_prefix_from_state_and_from_cameras(algo: str) -> None:
    """The wrapper sits outside the camera encoders and any policy: a loss that trains and a chunk of the right
    shape, told or not told the committed actions."""
    torch.manual_seed(0)
    small = {"act": {"d_model": 32, "heads": 2, "encoder_layers": 1, "vae_layers": 1, "feedforward": 64},
             "transformer": {"d_model": 32, "heads": 2, "layers": 1, "feedforward": 64}}.get(algo, {})
    for images in ((), (("obs.image_front", 16, 16),)):
        spec = PolicySpec(obs_dim=6, action_dim=3, horizon=8, images=images, prefix=3)
        policy = build_policy(algo, spec, small, encoder={"keypoints": 4, "features": 8})
        state = torch.randn(4, 1, 6)
        obs = {"state": state, "obs.image_front": torch.randint(0, 255, (4, 1, 16, 16, 3), dtype=torch.uint8)} \
            if images else state
        loss = policy.loss(obs, torch.randn(4, 8, 3), torch.zeros(4, 8, dtype=torch.bool))
        loss.backward()
        assert torch.isfinite(loss)
        policy.eval()
        told = dict(obs) if images else {"state": state}
        told.update({PREFIX: torch.randn(4, 3, 3), PREFIX_STEPS: torch.full((4,), 2)})
        assert policy.predict(obs).shape == policy.predict(told).shape == (4, 8, 3)


def test_a_camera_run_with_a_prefix_records_its_encoder(tmp_path: Path) -> None:
    from demo.policies.visuomotor import VisuomotorPolicy

    store = tmp_path / "img.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=4, seed=0, cameras=(("front", 32, 32),)), store, workers=0)
    train(TrainConfig(data=str(store), out=str(tmp_path / "run"), steps=4, batch_size=4, chunk=6, prefix_steps=2,
                      policy={"hidden": (16,)}, encoder={"keypoints": 4, "features": 8}))
    record = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())["policy"]
    assert record["encoder"]["keypoints"] == 4 and record["spec"]["prefix"] == 2
    bundle = ckpt.load_bundle(tmp_path / "run")
    assert isinstance(bundle.policy, CommittedPrefixPolicy) and isinstance(bundle.policy.inner, VisuomotorPolicy)
    assert bundle.policy.inner.encoder_config.features == 8
