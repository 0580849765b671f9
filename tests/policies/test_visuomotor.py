"""Visuomotor policies end to end: a pick store with two cameras -> BC / diffusion / DAgger from images."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.store import EpisodeStore
from demo.policies import checkpoint as ckpt
from demo.imitation.bc import train
from demo.training.config import TrainConfig
from demo.imitation.dagger import DaggerConfig, train_dagger
from demo.evaluation.evaluate import EvalConfig, evaluate

CAMERAS = (("front", 32, 32), ("wrist", 32, 24))  # (name, width, height): sizes may differ per camera


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("vis") / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=4, seed=0, cameras=CAMERAS), path, workers=0)
    return path


def tiny(store: Path, out: Path, **changes) -> TrainConfig:
    base = dict(data=str(store), out=str(out), steps=20, batch_size=8, chunk=4, log_every=10, val_every=10,
                policy={"hidden": (32,)}, encoder={"keypoints": 8, "features": 16})
    return TrainConfig(**{**base, **changes})


@pytest.mark.slow
def test_bc_trains_on_images_and_proprioception_and_runs_in_the_simulator(store: Path, tmp_path: Path) -> None:
    summary = train(tiny(store, tmp_path / "run"))
    assert np.isfinite(summary["train_loss"])
    policy = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())["policy"]
    # Cameras + the robot's own sensors; object poses are withheld unless asked for.
    assert policy["obs"]["images"] == {"obs.image_front": [32, 32, 3], "obs.image_wrist": [24, 32, 3]}
    assert policy["obs"]["keys"] == ["obs.joint_pos", "obs.gripper", "obs.ee_pos", "obs.ee_quat"]
    assert policy["encoder"]["backbone"] == "small" and policy["spec"]["images"][1] == ["obs.image_wrist", 24, 32]
    bundle = ckpt.load_bundle(tmp_path / "run")
    assert bundle.obs_spec.cameras() == [("front", 32, 32), ("wrist", 32, 24)]
    # The evaluation environment renders the cameras the policy reads; rollouts run end to end.
    result = evaluate(EvalConfig(run=str(tmp_path / "run"), episodes=2, device="cpu"))
    assert result["episodes"] == 2 and result["device"] == "cpu"
    assert all(d["length"] > 0 for d in result["episodes_detail"])


def test_same_seed_same_weights_and_crops_only_in_training(store: Path, tmp_path: Path) -> None:
    train(tiny(store, tmp_path / "a", steps=6))
    train(tiny(store, tmp_path / "b", steps=6))
    a = (tmp_path / "a" / ckpt.POLICY_FILE).read_bytes()
    assert a == (tmp_path / "b" / ckpt.POLICY_FILE).read_bytes()
    bundle = ckpt.load_bundle(tmp_path / "a")
    with EpisodeStore.open(store) as s:
        arrays, _ = s.load(["obs.image_front", "obs.image_wrist"])
    obs = {"state": torch.zeros(2, 1, bundle.obs_spec.dim),
           "obs.image_front": torch.from_numpy(arrays["obs.image_front"][:2, None]),
           "obs.image_wrist": torch.from_numpy(arrays["obs.image_wrist"][:2, None])}
    # Evaluation sees the centre crop: the same answer twice.
    assert torch.equal(bundle.policy.predict(obs), bundle.policy.predict(obs))


def test_one_camera_and_object_state_on_request(store: Path, tmp_path: Path) -> None:
    train(tiny(store, tmp_path / "run", obs_keys=("obs.image_wrist", "proprio", "obs.object_pos")))
    obs = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())["policy"]["obs"]
    assert list(obs["images"]) == ["obs.image_wrist"] and "obs.object_pos" in obs["keys"]
    with pytest.raises(DemoError, match="--encoder"):
        train(tiny(store, tmp_path / "bad", encoder={"backbone": "vgg"}))


@pytest.mark.slow
def test_diffusion_trains_on_images(store: Path, tmp_path: Path) -> None:
    summary = train(tiny(store, tmp_path / "run", algo="diffusion", steps=10, n_obs=2, chunk=8, execute=4,
                         policy={"width": 32, "depth": 1}))
    assert np.isfinite(summary["train_loss"])
    result = evaluate(EvalConfig(run=str(tmp_path / "run"), episodes=1, device="cpu"))
    assert result["episodes"] == 1


@pytest.mark.slow
def test_pixel_dagger_labels_the_states_the_pixel_policy_visits(store: Path, tmp_path: Path) -> None:
    config = DaggerConfig(train=tiny(store, tmp_path / "run", chunk=1), rounds=1, episodes_per_round=1, round_steps=5)
    summary = train_dagger(config)
    assert summary["rounds"][-1]["labels_total"] > summary["rounds"][0]["labels_total"]
    with EpisodeStore.open(tmp_path / "run" / "data.zarr") as agg:
        assert agg.num_episodes == 5  # 4 demonstrations + 1 labelled rollout, images included
        images, _ = agg.load(["obs.image_wrist"])
        assert images["obs.image_wrist"].shape[1:] == (24, 32, 3) and images["obs.image_wrist"].any()


def test_a_residual_corrects_a_pixel_policy(store: Path, tmp_path: Path) -> None:
    """Residual RL over a pixel policy: the environments render its cameras, the residual reads state, the
    demonstrations' BC term replays it over their images, and the run evaluates."""
    from demo.rl.config import PPOConfig, ResidualConfig
    from demo.rl.residual import train as train_residual

    train(tiny(store, tmp_path / "base", steps=6))
    out = tmp_path / "residual"
    train_residual(ResidualConfig(rl=PPOConfig(out=str(out), total_steps=40, num_envs=2, num_steps=20, epochs=1,
                                               minibatches=2, hidden=(16,), eval_episodes=1),
                                  init=str(tmp_path / "base"), data=str(store), demos=2))
    bundle = ckpt.load_bundle(out)
    assert bundle.obs_spec.images and bundle.residual is not None and not bundle.residual.obs_spec.images
    assert json.loads((out / ckpt.RUN_FILE).read_text())["demonstrations"]["episodes"] == 2
    result = evaluate(EvalConfig(run=str(out), episodes=1, device="cpu"))
    assert result["episodes"] == 1


def test_instructions_film_the_image_encoders_and_the_mlp_on_request(tmp_path: Path) -> None:
    """--text-opt film_images=true: coloured cubes from cameras, the instruction FiLMs each camera's feature maps
    (identity at initialisation, recorded, loaded back); without it the encoders take no condition. And
    film_image_head=true: it FiLMs BC's MLP behind the encoders, which otherwise gets it appended."""
    from demo.policies.instruction import CONDITION

    path = tmp_path / "colours.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=6, seed=0, cameras=CAMERAS, task_options={"colours": 3}),
                     path, workers=0)
    train(tiny(path, tmp_path / "film", text={"film_images": True, "dim": 16, "heads": 2}))
    train(tiny(path, tmp_path / "plain", text={"dim": 16, "heads": 2}))
    film, plain = ckpt.load_bundle(tmp_path / "film"), ckpt.load_bundle(tmp_path / "plain")
    assert film.run["policy"]["text"]["film_images"] is True and film.policy.film_images
    assert all(e.film is not None for e in film.policy.inner.cameras.values())
    assert all(e.film is None for e in plain.policy.inner.cameras.values())
    encoder = next(iter(film.policy.inner.cameras.values()))
    x = encoder.preprocess(torch.zeros(2, 32, 32, 3, dtype=torch.uint8) + 90)
    words = torch.randn(2, 16)
    with torch.no_grad():
        encoder.film.weight.zero_(), encoder.film.bias.zero_()
        assert torch.allclose(encoder.features(x, words), encoder.features(x))  # identity at zero
        encoder.film.weight.normal_()
        assert not torch.allclose(encoder.features(x, words), encoder.features(x))  # the words change what it sees
    with EpisodeStore.open(path) as s:
        arrays, _ = s.load(["obs.image_front", "obs.image_wrist"])
    obs = {"state": torch.zeros(1, 1, film.obs_spec.dim), "obs.image_front": torch.from_numpy(arrays["obs.image_front"][:1, None]),
           "obs.image_wrist": torch.from_numpy(arrays["obs.image_wrist"][:1, None]),
           "instruction": torch.from_numpy(film.tokenizer.encode(["pick up the red cube"]))}
    assert CONDITION in film.policy.condition(obs) and film.policy.predict(obs).shape[-1] == film.action.dim
    result = evaluate(EvalConfig(run=str(tmp_path / "film"), episodes=1, device="cpu"))
    assert result["episodes"] == 1

    # By default the words reach BC's MLP behind the cameras appended to the proprioception; with
    # film_image_head=true they FiLM its hidden layers as on state
    assert not plain.policy.film and plain.policy.inner.head.film is None
    train(tiny(path, tmp_path / "head", text={"dim": 16, "heads": 2, "film_image_head": True}))
    headed = ckpt.load_bundle(tmp_path / "head")
    assert headed.run["policy"]["text"]["film_image_head"] is True
    assert headed.policy.film and headed.policy.inner.head_condition and headed.policy.inner.head.film is not None
    assert plain.policy.inner.head.spec.obs_dim == headed.policy.inner.head.spec.obs_dim + 16  # appended, or not
    other = {**obs, "instruction": torch.from_numpy(headed.tokenizer.encode(["pick up the blue cube"]))}
    with torch.no_grad():
        for f in headed.policy.inner.head.film:
            f.weight.normal_()
        assert not torch.allclose(headed.policy.predict(obs), headed.policy.predict(other))  # the words reach the MLP


def test_an_auxiliary_target_trains_the_encoders_to_find_the_cube(store: Path, tmp_path: Path) -> None:
    """--aux-target obs.object_pos: the encoders learn to predict the cube's position (a loss beside the actions', in
    training only), the run records its width and reloads; the policy never reads it at evaluation."""
    from demo.policies.normalizer import OBS_CLIP
    from demo.policies.policy import build_policy
    from demo.policies.visuomotor import AUX_TARGET
    from demo.training.data import prepare

    config = tiny(store, tmp_path / "run", steps=150, aux_target="obs.object_pos", encoder={"keypoints": 8, "features": 16, "aux_weight": 1.0})
    with EpisodeStore.open(store) as s:
        data = prepare(config.resolved(), s)
    assert data.spec.aux_dim == 3 and data.aux.shape == (len(data.action), 3) and np.abs(data.aux).max() <= OBS_CLIP
    batch = data.windows(data.train_episodes).fixed(64, seed=0)
    obs, action, pad = batch
    assert AUX_TARGET in obs
    summary = train(config)
    bundle = ckpt.load_bundle(tmp_path / "run")
    policy = bundle.policy
    assert json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())["policy"]["spec"]["aux_dim"] == 3
    # Evaluation mode: the loss is the actions' alone (validation compares with runs without a target) ...
    policy.eval()
    without = {k: v for k, v in obs.items() if k != AUX_TARGET}
    assert policy.loss(obs, action, pad).item() == pytest.approx(policy.loss(without, action, pad).item())
    # ... and the trained encoders predict the cube's position far better than the untrained ones.
    torch.manual_seed(0)
    untrained = build_policy("bc", policy.spec, policy.config, policy.encoder_config).eval()
    with torch.no_grad():
        errors = [p.aux_error(p.encode(without), obs[AUX_TARGET]).item() for p in (policy, untrained)]
    assert errors[0] < 0.5 * errors[1], errors
    assert np.isfinite(summary["train_loss"])
    result = evaluate(EvalConfig(run=str(tmp_path / "run"), episodes=1, device="cpu"))
    assert result["episodes"] == 1


def test_an_auxiliary_target_is_refused_without_cameras_or_with_an_unknown_key(store: Path, tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="no low-dim observation 'obs.nope'"):
        train(tiny(store, tmp_path / "a", aux_target="obs.nope"))
    with pytest.raises(DemoError, match="reads no camera"):
        train(tiny(store, tmp_path / "b", aux_target="obs.object_pos", obs_keys=("proprio",)))
    with pytest.raises(DemoError, match="aux_weight"):
        train(tiny(store, tmp_path / "c", aux_target="obs.object_pos", encoder={"aux_weight": -1}))
    assert not (tmp_path / "a" / ckpt.POLICY_FILE).exists()
