"""BC's output heads (demo.policies.heads): shapes, likelihoods, sampling that keeps two modes apart, and
a gmm run through `demo train` / `demo eval`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import distributions as D

from demo.cli.main import main
from demo.errors import DemoError
from demo.training.config import HEAD_DEFAULTS, POLICY_DEFAULTS, for_policy
from demo.policies.heads import GMMHead, make_head
from demo.policies.policy import PolicySpec, build_policy

pytestmark = pytest.mark.usefixtures("torch_one_thread")

SPEC = PolicySpec(obs_dim=3, action_dim=2, n_obs=1, horizon=4)
HEAD_OPTS = {"mse": {}, "gmm": {"components": 3}, "discrete": {"bins": 16}}


@pytest.mark.parametrize("head", ["mse", "gmm", "discrete"])
def test_shapes_and_seeded_sampling(head: str) -> None:
    torch.manual_seed(0)
    policy = build_policy("bc", SPEC, {"hidden": (16,), "head": head, **HEAD_OPTS[head]})
    assert policy.net[-1].out_features == policy.head.width
    obs, action = torch.randn(5, 1, 3), torch.rand(5, 4, 2) * 2 - 1
    pad = torch.zeros(5, 4, dtype=torch.bool)
    assert policy.loss(obs, action, pad).shape == ()

    def draw(seed: int) -> torch.Tensor:
        return policy.eval().predict(obs, torch.Generator().manual_seed(seed))

    a = draw(1)
    assert a.shape == (5, 4, 2) and torch.equal(a, draw(1))  # same generator seed, same chunk
    if head != "mse":  # sampling heads differ with the seed somewhere in a batch of 5 x 8 numbers
        assert not torch.equal(a, draw(2))
        policy.head.temperature = 0.0  # the heaviest component / the likeliest bins: nothing left to chance
        assert torch.equal(draw(1), draw(2))
    if head == "discrete":  # every value is a bin centre
        centres = torch.linspace(-1, 1, 16)
        assert torch.isclose(a.reshape(-1, 1), centres).any(dim=1).all()


def test_gmm_likelihood_is_the_mixture_over_the_whole_chunk_and_pad_marginalises() -> None:
    torch.manual_seed(0)
    head = GMMHead(horizon=3, action_dim=2, components=4, min_std=0.01, low_noise=True)
    out, action = torch.randn(6, head.width), torch.randn(6, 3, 2)
    mean, scale, log_w = head.split(out)
    mixture = D.MixtureSameFamily(D.Categorical(logits=log_w),
                                  D.Independent(D.Normal(mean.flatten(2), scale.flatten(2)), 1))
    expected = (-mixture.log_prob(action.flatten(1)) / 6).mean()  # nats per action dimension
    assert head.loss(out, action, None).item() == pytest.approx(expected.item(), rel=1e-5)
    # Padded steps drop out exactly: their targets do not matter, the rest is the marginal.
    keep = torch.tensor([[True, True, False]] * 6)
    changed = action.clone()
    changed[:, 2] += 50.0
    assert head.loss(out, changed, keep).item() == pytest.approx(head.loss(out, action, keep).item(), rel=1e-6)
    marginal = D.MixtureSameFamily(D.Categorical(logits=log_w),
                                   D.Independent(D.Normal(mean[:, :, :2].flatten(2), scale[:, :, :2].flatten(2)), 1))
    assert head.loss(out, action, keep).item() == pytest.approx((-marginal.log_prob(action[:, :2].flatten(1)) / 4).mean().item(), rel=1e-5)


def test_gmm_wta_objective_fits_the_nearest_component_and_teaches_the_weights_its_index() -> None:
    """``objective=wta``: each chunk is assigned to the component whose mean is nearest (not the one
    that explains it best: a wide component at the average of two modes must not claim them); that
    component is fitted by its Gaussian NLL, the weights by cross-entropy on its index, the others pulled
    in by ``wta_epsilon`` times their squared distance. Padded steps drop out."""
    head = GMMHead(horizon=2, action_dim=1, components=2, min_std=0.01, low_noise=True, objective="wta", wta_epsilon=0.1)
    wide_at_average = [0.0, 0.0]  # component 0's mean; its scale is wide, its weight heavy
    mean = torch.tensor([wide_at_average, [0.3, 0.3]])  # component 1 nearer the target, but narrow
    raw_scale = torch.tensor([[3.0, 3.0], [-5.0, -5.0]])
    logits = torch.tensor([2.0, 0.0])
    out = torch.cat([mean.flatten(), raw_scale.flatten(), logits])[None]
    action = torch.tensor([[[0.6], [0.6]]])
    scale = torch.nn.functional.softplus(raw_scale[1]) + 0.01
    nll = (0.5 * ((0.6 - 0.3) / scale) ** 2 + scale.log() + 0.5 * math.log(2 * math.pi)).mean()
    mean_, scale_, log_w = head.split(out)
    log_p = D.Normal(mean_, scale_).log_prob(action[:, None]).sum(dim=(2, 3)) + log_w
    assert log_p.argmax().item() == 0  # by likelihood the wide component would take the chunk
    ce = -torch.log_softmax(logits, 0)[1]
    pull = 0.1 * 0.36  # the loser's mean squared distance, weighted by epsilon / (K - 1)
    assert head.loss(out, action, None).item() == pytest.approx((nll + ce + pull).item(), rel=1e-5)
    keep = torch.tensor([[True, False]])
    far = action.clone()
    far[:, 1] = -50.0  # a padded step's target decides nothing, not even the winner
    assert head.loss(out, far, keep).item() == pytest.approx(head.loss(out, action, None).item(), rel=1e-5)


def test_discrete_loss_is_cross_entropy_of_the_nearest_bin() -> None:
    head = make_head("discrete", 1, 1, bins=5)  # centres -1, -0.5, 0, 0.5, 1
    action = torch.tensor([[[0.3]]])  # nearest centre: 0.5, bin 3
    logits = torch.full((1, 5), -20.0)
    logits[0, 3] = 20.0
    assert head.loss(logits, action, None).item() < 1e-6
    assert head.loss(torch.zeros(1, 5), action, None).item() == pytest.approx(math.log(5), rel=1e-6)
    assert head.sample(logits).item() == 0.5


def test_discrete_bins_span_each_steps_own_range() -> None:
    """Fitted limits per step and dimension: a step whose targets span 0.02 gets its own 5 bins
    (not one bin of [-1, 1]'s), its targets land in distinct bins and sampling returns its centres."""
    head = make_head("discrete", 2, 1, bins=5)
    head.fit(np.array([[0.0], [-1.0]]), np.array([[0.02], [1.0]]))
    assert torch.allclose(head.centres()[0, 0], torch.tensor([0.0, 0.005, 0.01, 0.015, 0.02]))
    action = torch.tensor([[[0.011], [0.3]]])  # bins 2 (0.01) and 3 (0.5)
    logits = torch.full((1, 2, 1, 5), -20.0)
    logits[0, 0, 0, 2] = logits[0, 1, 0, 3] = 20.0
    assert head.loss(logits.flatten(1), action, None).item() < 1e-6
    assert torch.allclose(head.sample(logits.flatten(1)), torch.tensor([[[0.01], [0.5]]]))
    head.fit(np.zeros((2, 1)), np.zeros((2, 1)))  # a constant dimension: a narrow range, not a division by 0
    assert torch.isfinite(head.loss(logits.flatten(1), action, None))
    with pytest.raises(ValueError, match="limits must be"):
        head.fit(np.zeros((3, 1)), np.zeros((3, 1)))


@pytest.mark.parametrize("head, objective", [("mse", None), ("gmm", "wta"), ("gmm", "nll"), ("discrete", None)])
def test_training_lowers_the_loss_and_sampling_heads_keep_both_modes(head: str, objective: str | None) -> None:
    """A bimodal target: from the same observation the chunk is all +0.6 or all -0.6, half each. MSE
    regresses to their average; gmm (either objective) and discrete sample both sides, and gmm whole
    chunks from one side."""
    torch.manual_seed(0)
    options = {"hidden": (32, 32), "head": head, **HEAD_OPTS[head], **({"objective": objective} if objective else {})}
    policy = build_policy("bc", SPEC, options)
    opt = torch.optim.Adam(policy.parameters(), lr=3e-3)
    obs = torch.zeros(256, 1, 3)
    side = torch.where(torch.arange(256) % 2 == 0, 0.6, -0.6)
    action = side[:, None, None].expand(256, 4, 2).contiguous()
    pad = torch.zeros(256, 4, dtype=torch.bool)
    losses = []
    for _ in range(300):
        loss = policy.loss(obs, action, pad)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] - 0.01  # mse: down to 0.36, the modes' variance about their mean
    chunks = policy.eval().predict(obs[:200], torch.Generator().manual_seed(0))
    if head == "mse":
        assert chunks.abs().max() < 0.1  # the average of the modes, neither of them
        return
    share = (chunks > 0).float().mean().item()
    assert 0.3 < share < 0.7  # both sides, in about their proportion
    assert ((chunks.abs() - 0.6).abs() < 0.1).float().mean() > 0.9  # on a mode, not between them
    if head == "gmm":  # one component per chunk: every step and dimension on the same side
        assert ((chunks > 0).all(dim=(1, 2)) | (chunks < 0).all(dim=(1, 2))).all()


def test_head_options_are_checked() -> None:
    with pytest.raises(DemoError, match="head must be one of"):
        build_policy("bc", SPEC, {"head": "flow"})
    with pytest.raises(DemoError, match="bins"):
        build_policy("bc", SPEC, {"head": "discrete", "bins": "1"})
    with pytest.raises(DemoError, match="temperature"):
        build_policy("bc", SPEC, {"head": "gmm", "temperature": "-1"})
    with pytest.raises(DemoError, match="objective must be one of nll, wta"):
        build_policy("bc", SPEC, {"head": "gmm", "objective": "em"})
    # Every head is chunked and ensembled as BC is; a sampling head adds its own defaults (measured:
    # training/config.py), and a flag still wins.
    for head, settings in HEAD_DEFAULTS.items():
        config = for_policy("bc", policy={"head": head})
        assert (config.chunk, config.ensemble) == (POLICY_DEFAULTS["bc"]["chunk"], POLICY_DEFAULTS["bc"]["ensemble"])
        assert all(getattr(config, k) == v for k, v in settings.items())
    assert for_policy("bc").candidates == 1
    assert for_policy("bc", policy={"head": "gmm"}, candidates=2).candidates == 2
    assert (for_policy("bc", policy={"head": "discrete"}).chunk, for_policy("bc", policy={"head": "discrete"}).ensemble) == \
        (POLICY_DEFAULTS["bc"]["chunk"], POLICY_DEFAULTS["bc"]["ensemble"])


@pytest.fixture(scope="module")
def avoid_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.collect.scripted import CollectConfig, collect_scripted

    path = tmp_path_factory.mktemp("heads") / "avoid.zarr"
    collect_scripted(CollectConfig(task="avoid", episodes=4, seed=0), path, workers=0)
    return path


def test_gmm_run_records_its_head_and_evaluates_after_load(avoid_store: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "gmm"
    assert main(["train", str(avoid_store), "--out", str(run), "--head", "gmm", "--steps", "20", "--batch-size", "16",
                 "--chunk", "8", "--policy-opt", "hidden=32", "--policy-opt", "components=3"]) == 0
    record = json.loads((run / "run.json").read_text())["policy"]
    assert record["config"]["head"] == "gmm" and record["config"]["components"] == 3
    assert record["execution"] == {"execute": 1, "ensemble": 0.01}  # BC's execution
    capsys.readouterr()
    assert main(["eval", str(run), "--episodes", "2", "--json", "-"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["episodes"] == 2 and result["algo"] == "bc"
    # --head belongs to the MLP: one line for another algorithm
    assert main(["train", str(avoid_store), "--out", str(tmp_path / "x"), "--algo", "diffusion", "--head", "gmm"]) == 1
    assert "--head" in capsys.readouterr().err


def test_discrete_run_fits_its_bins_to_the_data_and_keeps_them(avoid_store: Path, tmp_path: Path) -> None:
    """Relative joint targets: step 0 spans less than the last step; the run's checkpoint keeps the ranges."""
    from demo.policies.checkpoint import load_bundle

    run = tmp_path / "discrete"
    assert main(["train", str(avoid_store), "--out", str(run), "--head", "discrete", "--steps", "5", "--batch-size", "16",
                 "--chunk", "8", "--policy-opt", "hidden=16", "--policy-opt", "bins=8"]) == 0
    head = load_bundle(run).policy.head
    span = (head.high - head.low)[:, :7]  # the arm's joints (relative); the gripper is absolute
    assert (span[0] < 0.5 * span[-1]).all() and (head.low >= -1.0 - 1e-5).all() and (head.high <= 1.0 + 1e-5).all()
