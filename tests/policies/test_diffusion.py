"""The diffusion policy: it learns a two-mode distribution that MSE regression averages, samples
deterministically for a seed, and survives a checkpoint round trip sample for sample. Flow matching
(demo.policies.flow) on the same toy problem, with 1, 4 and 10 Euler steps, at the end."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from demo.errors import DemoError
from demo.training.config import POLICY_DEFAULTS
from demo.policies.diffusion import DiffusionConfig, DiffusionPolicy, with_sampler
from demo.policies.flow import FlowPolicy
from demo.policies.policy import PolicySpec, build_policy

H = 8
RAMP = 0.2 + 0.6 * torch.arange(H) / (H - 1)


# before any module-scoped fixture (e.g. a trained policy): it comes first in the closure
pytestmark = pytest.mark.usefixtures("torch_one_thread")


def toy_batch(n: int, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Observation ``c`` in [-1, 1]; chunk: dim 0 ramps up or down (a fair coin), dim 1 = c / 2."""
    c = torch.rand(n, 1, generator=g) * 2 - 1
    side = torch.randint(0, 2, (n, 1), generator=g).float() * 2 - 1
    action = torch.stack([side * RAMP, (c / 2).expand(n, H)], dim=-1)
    obs = torch.cat([c, torch.zeros(n, 1)], dim=-1)[:, None, :]
    return obs, action


def distance_to_modes(obs: torch.Tensor, chunk: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Max-abs distance of each chunk to its nearer mode, and whether that is the upward one."""
    up = torch.stack([RAMP.expand(len(obs), H), (obs[:, 0, :1] / 2).expand(-1, H)], dim=-1)
    down = up * torch.tensor([-1.0, 1.0])
    d_up, d_down = (chunk - up).abs().amax((1, 2)), (chunk - down).abs().amax((1, 2))
    return torch.minimum(d_up, d_down), d_up < d_down


def fit(policy: torch.nn.Module, steps: int, lr: float = 3e-3, seed: int = 0) -> torch.nn.Module:
    torch.manual_seed(seed)
    opt = torch.optim.AdamW(policy.parameters(), lr=lr)
    g = torch.Generator().manual_seed(seed)
    policy.train()
    for _ in range(steps):
        obs, action = toy_batch(128, g)
        loss = policy.loss(obs, action, torch.zeros(action.shape[:2], dtype=torch.bool))
        opt.zero_grad()
        loss.backward()
        opt.step()
    return policy.eval()


TINY = {"unet": {"denoiser": "unet", "channels": (16, 32), "step_embed_dim": 16}, "mlp": {"denoiser": "mlp", "width": 64, "depth": 2, "step_embed_dim": 16}}


def tiny_diffusion(denoiser: str = "unet", **options) -> DiffusionPolicy:
    torch.manual_seed(0)
    return build_policy("diffusion", PolicySpec(2, 2, 1, H), {**TINY[denoiser], **options})


@pytest.fixture(scope="module", params=[pytest.param("unet", marks=pytest.mark.slow), "mlp"])  # unet: 16 s to fit
def trained(request) -> DiffusionPolicy:
    return fit(tiny_diffusion(request.param), 300)


@pytest.mark.parametrize("sampler,steps", [("ddim", 4), ("ddim", 8), ("ddpm", 100)])
def test_diffusion_recovers_both_modes(trained: DiffusionPolicy, sampler: str, steps: int) -> None:
    obs, _ = toy_batch(400, torch.Generator().manual_seed(7))
    with torch.inference_mode():
        chunk = with_sampler(copy.deepcopy(trained), steps=steps, sampler=sampler).predict(obs, torch.Generator().manual_seed(1))
    dist, up = distance_to_modes(obs, chunk)
    assert float(dist.quantile(0.9)) < 0.2, "samples lie on a mode"
    assert 0.3 < float(up.float().mean()) < 0.7, "and both modes are sampled"


@pytest.mark.slow
def test_sample_prediction_is_why_few_step_ddim_works() -> None:
    """The default prediction="sample": after a short training, epsilon prediction's x0 estimate at
    t = 99 (eps error amplified ~2000x) leaves 4-step DDIM chunks far off the modes; x0 does not."""
    obs, _ = toy_batch(400, torch.Generator().manual_seed(7))
    p90 = {}
    for prediction in ("epsilon", "sample"):
        policy = with_sampler(fit(tiny_diffusion("mlp", prediction=prediction), 300), steps=4)
        with torch.inference_mode():
            dist, _ = distance_to_modes(obs, policy.predict(obs, torch.Generator().manual_seed(1)))
        p90[prediction] = float(dist.quantile(0.9))
    assert p90["sample"] < 0.2 and p90["epsilon"] > 3 * p90["sample"]


def test_mse_regression_averages_the_modes() -> None:
    """The contrast that motivates diffusion: an MSE-trained chunk predictor lands between modes."""
    bc = fit(build_policy("bc", PolicySpec(2, 2, 1, H), {"hidden": (64, 64)}), 300)
    obs, _ = toy_batch(400, torch.Generator().manual_seed(7))
    with torch.inference_mode():
        dist, _ = distance_to_modes(obs, bc.predict(obs))
    assert float(dist.quantile(0.1)) > 0.15


def test_sampling_is_seeded_and_jit_matches_eager(trained: DiffusionPolicy) -> None:
    obs = toy_batch(1, torch.Generator().manual_seed(3))[0]
    policy = copy.deepcopy(trained)
    with torch.inference_mode():
        a = policy.predict(obs, torch.Generator().manual_seed(5))
        b = policy.predict(obs, torch.Generator().manual_seed(5))
        c = policy.predict(obs, torch.Generator().manual_seed(6))
        eager = with_sampler(policy, jit=False).predict(obs, torch.Generator().manual_seed(5))
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert torch.allclose(a, eager, atol=1e-4)


def test_inference_cache_follows_the_weights(trained: DiffusionPolicy) -> None:
    """The cached FiLM table and frozen trace must not outlive a weight update (EMA copy, load)."""
    obs = toy_batch(1, torch.Generator().manual_seed(3))[0]
    policy = copy.deepcopy(trained)
    fresh = tiny_diffusion(trained.config.denoiser).eval()
    with torch.inference_mode():
        before = policy.predict(obs, torch.Generator().manual_seed(5))
        policy.load_state_dict(fresh.state_dict())
        after = policy.predict(obs, torch.Generator().manual_seed(5))
        expected = fresh.predict(obs, torch.Generator().manual_seed(5))
    assert not torch.equal(before, after)
    assert torch.allclose(after, expected, atol=1e-5)


def test_checkpoint_round_trip_gives_identical_samples(trained: DiffusionPolicy, tmp_path) -> None:
    from demo.store import ActionSpec
    from demo.policies import checkpoint as ckpt
    from demo.policies.actor import ExecConfig
    from demo.policies.normalizer import MinMaxNormalizer
    from demo.policies.observation import ObsSpec

    obs_spec = ObsSpec(("obs.c",), (2,))
    norm = MinMaxNormalizer(np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    action = ActionSpec("joint_pos", ("a", "b"), ("rad", "rad"))
    record = ckpt.policy_record("diffusion", trained, obs_spec, action, ExecConfig(execute=4))
    ckpt.write_run(tmp_path, {"policy": record})
    ckpt.save_policy(tmp_path, trained.state_dict(), norm, norm)
    bundle = ckpt.load_bundle(tmp_path)
    assert isinstance(bundle.policy, DiffusionPolicy) and bundle.policy.config == trained.config
    obs = toy_batch(3, torch.Generator().manual_seed(3))[0]
    with torch.inference_mode():
        for seed in (0, 1):
            a = trained.predict(obs, torch.Generator().manual_seed(seed))
            b = bundle.policy.predict(obs, torch.Generator().manual_seed(seed))
            assert torch.equal(a, b)
    # the receding-horizon executor: a new chunk every `execute` steps, same actions for a seed
    actors = [bundle.actor(), ckpt.load_bundle(tmp_path).actor()]
    runs = []
    for actor in actors:
        actor.reset(11)
        runs.append(np.stack([actor.act({"obs.c": np.array([0.3, 0.0], np.float32)}) for _ in range(10)]))
        assert actor.queries == 3  # steps 0, 4, 8
    assert np.array_equal(runs[0], runs[1])


@pytest.mark.parametrize("denoiser", ["unet", "mlp"])
def test_cached_conditioning_is_exact(denoiser: str) -> None:
    """predict() adds cached observation and timestep parts; their sum must be the full network."""
    net = tiny_diffusion(denoiser).net.eval()
    x, t, obs = torch.randn(3, H, 2), torch.tensor([0, 40, 99]), torch.randn(3, 2)
    with torch.no_grad():
        assert torch.allclose(net.denoise(x, net.film_from_obs(obs) + net.film_from_step(t)), net(x, t, obs), atol=1e-5)
        assert (net(x, t, obs + 0.3) - net(x, t, obs)).abs().max() > 1e-4


def test_config_checks_and_defaults() -> None:
    defaults = POLICY_DEFAULTS["diffusion"]
    assert defaults["chunk"] == 16 and defaults["n_obs"] == 2 and defaults["execute"] == 4 and defaults["steps"] == 16000
    assert DiffusionConfig().train_steps == 100 and DiffusionConfig(large=True).net_channels == (256, 512, 1024)
    assert defaults["ensemble"] is False  # averaging chunks across modes is what diffusion avoids
    for bad in ({"prediction": "v"}, {"sampler": "euler"}, {"inference_steps": 0}, {"inference_steps": 101},
                {"channels": (30,)}, {"spacing": "cubic"}, {"denoiser": "transformer"}):
        with pytest.raises(DemoError):
            build_policy("diffusion", PolicySpec(2, 2, 1, H), bad)
    with pytest.raises(DemoError, match="multiple of 4"):
        build_policy("diffusion", PolicySpec(2, 2, 1, 10), {"denoiser": "unet", "channels": (16, 32, 64)})


def test_trained_run_round_trip(tmp_path) -> None:
    """demo train's run directory: the saved policy is the EMA of training and samples identically."""
    from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
    from demo.policies import checkpoint as ckpt
    from demo.imitation.bc import train
    from demo.training.config import for_policy

    meta = StoreMeta(fps=20.0, features={"obs.c": FeatureSpec((2,), "float32", "toy condition")},
                     action=ActionSpec("joint_pos", ("a", "b"), ("rad", "rad")), task={"name": "toy"})
    store = EpisodeStore.create(tmp_path / "toy.zarr", meta)
    g = torch.Generator().manual_seed(0)
    for _ in range(6):
        obs, action = toy_batch(1, g)
        store.append_episode({"obs.c": obs[0].expand(H, 2).numpy().copy(), "action": action[0].numpy()}, success=True)
    store.close()
    out = tmp_path / "run"
    config = for_policy("diffusion", data=str(tmp_path / "toy.zarr"), out=str(out), steps=30, batch_size=16, warmup_steps=2,
                          val_fraction=0.0, chunk=H, execute=4, log_every=10, policy=dict(TINY["mlp"]))
    train(config)
    bundle = ckpt.load_bundle(out)
    assert bundle.algo == "diffusion" and bundle.execution.execute == 4 and bundle.execution.ensemble is None
    ema = build_policy("diffusion", bundle.policy.spec, bundle.policy.config)
    ema.load_state_dict(ckpt.load_train_state(out)["ema"])
    history = np.array([[[0.3, 0.0]] * bundle.policy.spec.n_obs], np.float32)  # [1, n_obs, 2]
    obs = torch.from_numpy(bundle.obs_norm.normalize(history))
    with torch.inference_mode():
        a = bundle.policy.predict(obs, torch.Generator().manual_seed(2))
        b = ckpt.load_bundle(out).policy.predict(obs, torch.Generator().manual_seed(2))
        c = ema.eval().predict(obs, torch.Generator().manual_seed(2))
    assert torch.equal(a, b) and torch.equal(a, c)


# ---------------------------------------------------------------------------------- flow matching


@pytest.fixture(scope="module")
def trained_flow() -> FlowPolicy:
    torch.manual_seed(0)
    return fit(build_policy("flow", PolicySpec(2, 2, 1, H), TINY["mlp"]), 1500)  # ~3 s; at 400 steps 10-step p90 0.30


@pytest.mark.parametrize("steps,p90", [(4, 0.35), (10, 0.15)])  # fewer Euler steps, coarser chunks
def test_flow_recovers_both_modes(trained_flow: FlowPolicy, steps: int, p90: float) -> None:
    obs, _ = toy_batch(400, torch.Generator().manual_seed(7))
    trained_flow.config.inference_steps = steps
    with torch.inference_mode():
        chunk = trained_flow.predict(obs, torch.Generator().manual_seed(1))
    dist, up = distance_to_modes(obs, chunk)
    assert float(dist.quantile(0.9)) < p90, "samples lie on a mode"
    assert 0.3 < float(up.float().mean()) < 0.7, "and both modes are sampled"


def test_one_euler_step_is_the_mean_velocity(trained_flow: FlowPolicy) -> None:
    """One step from noise lands on the average of the modes' velocities: between the modes, as MSE does."""
    obs, _ = toy_batch(400, torch.Generator().manual_seed(7))
    trained_flow.config.inference_steps = 1
    with torch.inference_mode():
        dist, _ = distance_to_modes(obs, trained_flow.predict(obs, torch.Generator().manual_seed(1)))
    trained_flow.config.inference_steps = 10
    assert float(dist.quantile(0.5)) > 0.15


def test_flow_sampling_is_seeded(trained_flow: FlowPolicy) -> None:
    obs = toy_batch(1, torch.Generator().manual_seed(3))[0]
    with torch.inference_mode():
        a, b, c = (trained_flow.predict(obs, torch.Generator().manual_seed(s)) for s in (5, 5, 6))
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_flow_config_is_checked() -> None:
    with pytest.raises(Exception, match="time_sampling"):
        build_policy("flow", PolicySpec(2, 2, 1, H), {"time_sampling": "gamma"})
    with pytest.raises(Exception, match="inference_steps"):
        build_policy("flow", PolicySpec(2, 2, 1, H), {"inference_steps": 0})
