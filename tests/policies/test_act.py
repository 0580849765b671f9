"""ACT (demo.policies.act): shapes, the CVAE loss, deterministic inference, `demo train --algo act` /
`demo eval`, and ACT behind image encoders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from demo.cli.main import main
from demo.errors import DemoError
from demo.policies.act import ACTPolicy
from demo.training.config import POLICY_DEFAULTS, for_policy
from demo.policies.policy import PolicySpec, build_policy, policy_class

pytestmark = pytest.mark.usefixtures("torch_one_thread")

SPEC = PolicySpec(obs_dim=5, action_dim=3, n_obs=2, horizon=6)
TINY = {"d_model": 32, "heads": 2, "feedforward": 64, "latent_dim": 8, "dropout": 0.0}


def batch(b: int = 8) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    obs = torch.randn(b, 2, 5, generator=g)
    action = torch.tanh(obs[:, -1:, :3] + 0.1 * torch.arange(6.0)[None, :, None])  # a smooth function of obs
    pad = torch.zeros(b, 6, dtype=torch.bool)
    pad[: b // 2, 4:] = True
    return obs, action, pad


def test_registered_shapes_and_options() -> None:
    assert policy_class("act") is ACTPolicy
    policy = build_policy("act", SPEC, TINY)
    obs, action, pad = batch()
    mu, logvar = policy.posterior(obs, action, pad)
    assert mu.shape == logvar.shape == (8, 8)
    assert policy.loss(obs, action, pad).shape == ()
    assert policy.eval().predict(obs).shape == (8, 6, 3)
    with pytest.raises(DemoError, match="divisible by heads"):
        build_policy("act", SPEC, {"d_model": 30, "heads": 4})
    with pytest.raises(DemoError, match="latent"):
        build_policy("act", SPEC, {"latent": "mean"})
    config = for_policy("act")
    assert all(getattr(config, k) == v for k, v in POLICY_DEFAULTS["act"].items())


def test_from_cameras_the_joints_and_each_camera_are_tokens_and_training_hides_the_joints() -> None:
    spec = PolicySpec(obs_dim=5, action_dim=3, n_obs=2, horizon=6, token_dims=(2, 3))  # joints (2), a camera (3)
    torch.manual_seed(0)
    policy = build_policy("act", spec, TINY).eval()
    assert policy.memory_pos.shape[1] == 1 + 2 * 2  # z, then per frame: joints, camera
    obs, action, pad = batch()
    z = torch.zeros(8, 8)
    other_joints = obs.clone()
    other_joints[..., :2] += 1.0
    other_camera = obs.clone()
    other_camera[..., 2:] += 1.0
    hidden = torch.ones(8, dtype=torch.bool)
    # joints hidden from attention: the chunk no longer depends on them, and still on the camera
    assert torch.allclose(policy.decode(obs, z, hidden), policy.decode(other_joints, z, hidden), atol=1e-6)
    assert not torch.allclose(policy.decode(obs, z, hidden), policy.decode(other_camera, z, hidden), atol=1e-3)
    assert not torch.allclose(policy.decode(obs, z), policy.decode(other_joints, z), atol=1e-3)
    # the CVAE encoder reads the joints only (ACT's)
    assert torch.allclose(policy.posterior(obs, action, pad)[0], policy.posterior(other_camera, action, pad)[0])
    # training draws which samples' joints to hide: none at 0, so the loss matches the unhidden decode's
    never = build_policy("act", spec, {**TINY, "state_dropout": 0.0}).train()
    never.load_state_dict(policy.state_dict())
    torch.manual_seed(1)
    with_dropout = policy.train().loss(obs, action, pad).item()
    torch.manual_seed(1)
    without = never.loss(obs, action, pad).item()
    assert with_dropout != pytest.approx(without, abs=1e-6)
    with pytest.raises(DemoError, match="state_dropout"):
        build_policy("act", spec, {"state_dropout": 1.0})


def test_loss_is_l1_on_unpadded_steps_plus_weighted_kl() -> None:
    torch.manual_seed(0)
    policy = build_policy("act", SPEC, {**TINY, "kl_weight": 0.0}).eval()  # eval: no dropout
    torch.nn.init.normal_(policy.latent_proj.weight, std=0.1)  # a posterior away from the prior it starts as
    obs, action, pad = batch()

    def loss(a: torch.Tensor) -> float:
        torch.manual_seed(1)  # the same reparameterisation noise every time
        return policy.loss(obs, a, pad).item()

    l1 = loss(action)
    changed = action.clone()
    changed[pad] += 10.0  # padded steps: neither the CVAE encoder nor the L1 sees them
    assert loss(changed) == pytest.approx(l1, abs=1e-6)
    changed[0, 0] += 10.0  # a kept step does
    assert loss(changed) > l1 + 0.1
    mu, logvar = policy.posterior(obs, action, pad)
    kl = (-0.5 * (1 + logvar - mu.square() - logvar.exp())).sum(-1).mean().item()  # per sample, summed over z
    assert kl > 0
    policy.config.kl_weight = 10.0
    assert loss(action) == pytest.approx(l1 + 10.0 * kl, rel=1e-5)


def test_training_lowers_the_loss_and_inference_is_deterministic() -> None:
    torch.manual_seed(0)
    policy = build_policy("act", SPEC, TINY)
    obs, action, pad = batch(32)
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-3)
    losses = []
    for _ in range(80):
        loss = policy.train().loss(obs, action, pad)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert sum(losses[-10:]) < 0.5 * sum(losses[:10])
    policy.eval()
    # z = 0 (the paper): no randomness, whatever the generator
    policy.config.latent = "zero"
    a = policy.predict(obs, torch.Generator().manual_seed(1))
    assert torch.equal(a, policy.predict(obs, torch.Generator().manual_seed(2)))
    assert (a - action).abs().mean() < 0.5 * (action - action.mean()).abs().mean()  # it learned the chunks
    # latent=sample: z from the prior, seeded by the rollout's generator
    policy.config.latent = "sample"
    b = policy.predict(obs, torch.Generator().manual_seed(1))
    assert torch.equal(b, policy.predict(obs, torch.Generator().manual_seed(1)))
    assert not torch.equal(b, policy.predict(obs, torch.Generator().manual_seed(2)))
    # sample: another z at the next query of the same rollout; commit: the same z all episode
    g = torch.Generator().manual_seed(1)
    assert torch.equal(policy.predict(obs, g), b) and not torch.equal(policy.predict(obs, g), b)
    policy.config.latent = "commit"
    g = torch.Generator().manual_seed(1)
    c = policy.predict(obs, g)
    assert torch.equal(c, b) and torch.equal(policy.predict(obs, g), c)
    assert not torch.equal(c, policy.predict(obs, torch.Generator().manual_seed(2)))


@pytest.mark.slow
@pytest.mark.parametrize("kl_weight", [0.01, 10.0])
def test_a_light_kl_lets_the_latent_carry_the_mode(kl_weight: float) -> None:
    """A bimodal target: from one observation the chunk is all +0.6 or all -0.6, half each. With the
    default KL weight the latent carries the side and committed draws land on both modes, each whole;
    with the paper's 10 it does not, and the draws land between them."""
    torch.manual_seed(0)
    policy = build_policy("act", SPEC, {**TINY, "kl_weight": kl_weight})
    obs = torch.zeros(128, 2, 5)
    side = torch.where(torch.arange(128) % 2 == 0, 0.6, -0.6)
    action = side[:, None, None].expand(128, 6, 3).contiguous()
    pad = torch.zeros(128, 6, dtype=torch.bool)
    opt = torch.optim.AdamW(policy.parameters(), lr=1e-3)
    for _ in range(300):
        loss = policy.train().loss(obs, action, pad)
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()
    draws = torch.cat([policy.predict(obs[:1], torch.Generator().manual_seed(s)) for s in range(40)])  # [40, 6, 3]
    on_a_mode = ((draws.abs() - 0.6).abs() < 0.15).all(dim=(1, 2))
    positive = (draws > 0).all(dim=(1, 2))
    if kl_weight == 0.01:
        assert on_a_mode.float().mean() > 0.8
        assert 0.2 < positive[on_a_mode].float().mean() < 0.8
    else:
        assert on_a_mode.float().mean() < 0.2  # between the modes (L1's median), whatever z


@pytest.fixture(scope="module")
def avoid_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.collect.scripted import CollectConfig, collect_scripted

    path = tmp_path_factory.mktemp("act") / "avoid.zarr"
    collect_scripted(CollectConfig(task="avoid", episodes=4, seed=0), path, workers=0)
    return path


def test_train_and_eval_from_the_command_line(avoid_store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "act"
    opts = [x for k, v in TINY.items() for x in ("--policy-opt", f"{k}={v}")]
    assert main(["train", str(avoid_store), "--out", str(run), "--algo", "act", "--steps", "20", "--batch-size", "16",
                 "--chunk", "8", *opts]) == 0
    record = json.loads((run / "run.json").read_text())["policy"]
    assert record["algo"] == "act" and record["config"]["d_model"] == 32 and record["spec"]["horizon"] == 8
    assert record["execution"] == {"execute": 1, "ensemble": 0.01}  # a query every step, ACT's ensembling
    capsys.readouterr()
    assert main(["eval", str(run), "--episodes", "2", "--json", "-"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["episodes"] == 2 and result["algo"] == "act"


@pytest.mark.slow
def test_act_behind_image_encoders(tmp_path: Path) -> None:
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.policies import checkpoint as ckpt
    from demo.imitation.bc import train
    from demo.training.config import TrainConfig
    from demo.evaluation.evaluate import EvalConfig, evaluate
    from demo.policies.visuomotor import VisuomotorPolicy

    store = tmp_path / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=3, seed=0, cameras=(("front", 24, 24),)), store, workers=0)
    run = tmp_path / "run"
    summary = train(TrainConfig(data=str(store), out=str(run), algo="act", steps=6, batch_size=4, chunk=4, log_every=3,
                                val_every=3, val_fraction=0.34, policy=TINY, encoder={"keypoints": 4, "features": 8}))
    assert summary["step"] == 6
    # the camera check: the validation loss again with the images shuffled across the windows
    assert summary["val_loss_images_shuffled"] > 0 and isinstance(summary["reads_cameras"], bool)
    bundle = ckpt.load_bundle(run)
    assert isinstance(bundle.policy, VisuomotorPolicy) and isinstance(bundle.policy.head, ACTPolicy)
    # the wrapped ACT sees each frame's state and camera features, a token each
    assert bundle.policy.head.spec.obs_dim == bundle.obs_spec.dim + 8
    assert bundle.policy.head.sizes == [bundle.obs_spec.dim, 8]
    result = evaluate(EvalConfig(run=str(run), episodes=1, device="cpu"))
    assert result["episodes"] == 1 and result["episodes_detail"][0]["length"] > 0
