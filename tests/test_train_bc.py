"""Behaviour cloning on synthetic stores: it learns, splits as asked, resumes bit-exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.train import checkpoint as ckpt
from demo.train.bc import BatchSource, TrainConfig, setup, train

torch.set_num_threads(1)


def make_store(path: Path, episodes: int = 24, length: int = 30, seed: int = 0) -> Path:
    """Actions are a fixed smooth function of the observation (plus a joint target near obs.joint_pos)."""
    meta = StoreMeta(
        fps=20.0,
        features={
            "obs.joint_pos": FeatureSpec((2,), "float32"),
            "obs.joint_vel": FeatureSpec((2,), "float32"),
            "obs.object_pos": FeatureSpec((1, 3), "float32"),
            "obs.image_front": FeatureSpec((4, 4, 3), "uint8"),
        },
        action=ActionSpec("joint_pos", ("j0.target", "j1.target", "gripper"), ("rad", "rad", "1")),
        robot={"name": "synthetic", "config": "builtin"},
        task={"name": "synthetic", "options": {}, "horizon": length},
    )
    rng = np.random.default_rng(seed)
    with EpisodeStore.create(path, meta) as store:
        for i in range(episodes):
            q = rng.uniform(-1, 1, (length, 2)).astype(np.float32)
            obj = rng.uniform(-1, 1, (length, 1, 3)).astype(np.float32)
            delta = 0.05 * np.tanh(obj[:, 0, :2] * 2)
            grip = (obj[:, 0, 2:] > 0).astype(np.float32)
            action = np.concatenate([q + delta, grip], axis=1)
            store.append_episode(
                {"obs.joint_pos": q, "obs.joint_vel": np.zeros_like(q), "obs.object_pos": obj,
                 "obs.image_front": np.zeros((length, 4, 4, 3), np.uint8), "action": action},
                success=i % 6 != 5, seed=100 + i, source="synthetic",
            )
    return path


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_store(tmp_path_factory.mktemp("bc") / "data.zarr")


def config(data: Path, out: Path, **kw) -> TrainConfig:
    base = dict(data=str(data), out=str(out), steps=300, batch_size=64, lr=3e-3, warmup_steps=20,
                policy={"hidden": (64, 64)}, log_every=50, val_every=100)
    return TrainConfig(**{**base, **kw})


def test_bc_learns_the_mapping(data: Path, tmp_path: Path) -> None:
    summary = train(config(data, tmp_path / "run"), progress=False)
    metrics = json.loads((tmp_path / "run" / ckpt.METRICS_FILE).read_text())
    first_val = metrics["val_loss"][0][1]
    assert metrics["val_loss"][0][0] == 0 and summary["val_loss"] < first_val / 5
    # Failed episodes (every 6th) are left out by default; a validation split was drawn.
    run = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())
    used = set(run["data"]["train_episodes"]) | set(run["data"]["val_episodes"])
    assert used == {i for i in range(24) if i % 6 != 5}
    assert len(run["data"]["val_episodes"]) == 2
    # Default observation: low-dim keys without velocities and images; [1, 3] objects flattened.
    assert run["policy"]["obs"] == {"keys": ["obs.joint_pos", "obs.object_pos"], "dims": [2, 3], "transforms": ["", ""]}
    assert run["policy"]["relative_actions"] == {"obs_key": "obs.joint_pos", "obs_dims": [0, 1], "action_dims": [0, 1]}


def test_relative_actions_and_chunks_in_batches(data: Path) -> None:
    with EpisodeStore.open(data) as store:
        s = setup(config(data, Path("unused"), chunk=3, include_failures=True, val_fraction=0.0), store)
        raw, ends = store.load(["action", "obs.joint_pos"])
    source = BatchSource(s.data, s.data.train_episodes, n_obs=1, horizon=3)
    t = np.array([0, 5, 29])  # 29 is the last frame of episode 0: chunk steps 1, 2 are padding
    obs, action, pad = source.get(t)
    rel = s.action_norm.unnormalize(action.numpy())
    for row, frame in enumerate(t):
        for k in range(3):
            target = raw["action"][min(frame + k, 29)]
            assert np.allclose(rel[row, k, :2] + raw["obs.joint_pos"][frame], target[:2], atol=1e-5)
            assert rel[row, k, 2] == pytest.approx(target[2], abs=1e-5)
    assert pad[2].tolist() == [False, True, True]
    assert action.abs().max() <= 1.0 + 1e-5


def test_masks_choose_the_split(data: Path, tmp_path: Path) -> None:
    copy = make_store(tmp_path / "masked.zarr")
    with EpisodeStore.open(copy, "a") as store:
        store.set_mask("val", np.arange(24) < 4)
        store.set_mask("keep", np.arange(24) < 12)
    train(config(copy, tmp_path / "run", steps=20, val_mask="val", train_mask="keep", include_failures=True), progress=False)
    run = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())
    assert run["data"]["val_episodes"] == [0, 1, 2, 3]
    assert run["data"]["train_episodes"] == list(range(4, 12))
    with pytest.raises(DemoError, match="no mask 'nope'"):
        train(config(copy, tmp_path / "run2", val_mask="nope"), progress=False)


def test_resume_continues_bit_exactly(data: Path, tmp_path: Path) -> None:
    straight = config(data, tmp_path / "straight", steps=80, ema=0.9, obs_noise=0.01)
    train(straight, progress=False)
    split = config(data, tmp_path / "split", steps=80, ema=0.9, obs_noise=0.01)
    train(split, progress=False, stop_at=30)
    assert ckpt.load_train_state(tmp_path / "split")["step"] == 30
    train(split, progress=False, resume=True)
    a = ckpt.load_train_state(tmp_path / "straight")
    b = ckpt.load_train_state(tmp_path / "split")
    assert b["step"] == 80
    for key in a["policy"]:
        assert torch.equal(a["policy"][key], b["policy"][key]), key
        assert torch.equal(a["ema"][key], b["ema"][key]), key


def test_run_directory_is_protected(data: Path, tmp_path: Path) -> None:
    train(config(data, tmp_path / "run", steps=5), progress=False)
    with pytest.raises(DemoError, match="already exists"):
        train(config(data, tmp_path / "run", steps=5), progress=False)
    with pytest.raises(DemoError, match="cannot resume with a different chunk"):
        train(config(data, tmp_path / "run", steps=10, chunk=2), progress=False, resume=True)
    with pytest.raises(DemoError, match="nothing to resume"):
        train(config(data, tmp_path / "fresh", steps=5), progress=False, resume=True)
    (tmp_path / "notarun").mkdir()
    (tmp_path / "notarun" / "precious.txt").write_text("keep me")
    with pytest.raises(DemoError, match="not a training run"):
        train(config(data, tmp_path / "notarun", steps=5), progress=False, overwrite=True)
    assert (tmp_path / "notarun" / "precious.txt").exists()


def test_bad_options_fail_before_training(data: Path, tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="--execute"):
        train(config(data, tmp_path / "r", chunk=2, execute=3), progress=False)
    with pytest.raises(DemoError, match="has no observation 'obs.nope'"):
        train(config(data, tmp_path / "r", obs_keys=("obs.nope",)), progress=False)
    with pytest.raises(DemoError, match="not a low-dimensional"):
        train(config(data, tmp_path / "r", obs_keys=("obs.image_front",)), progress=False)
    with pytest.raises(DemoError, match="unknown policy"):
        train(config(data, tmp_path / "r", algo="transformer"), progress=False)
    assert not (tmp_path / "r").exists()


def test_label_flags_choose_windows_and_pad_unlabelled_steps() -> None:
    from demo.train.bc import Dataset

    n = 10
    labelled = np.array([1, 1, 0, 0, 1, 1, 1, 0, 1, 1], dtype=bool)
    data = Dataset(obs=np.arange(n, dtype=np.float32)[:, None], action=np.arange(n, dtype=np.float32)[:, None],
                   base=None, action_norm=None, ends=np.array([n]), train_episodes=np.array([0]),
                   val_episodes=np.zeros(0, int), labelled=labelled)
    source = BatchSource(data, np.array([0]), n_obs=1, horizon=3)
    assert source.sampler.indices.tolist() == [0, 1, 4, 5, 6, 8, 9]
    obs, action, pad = source.get(np.array([1, 6, 9]))
    assert action[:, :, 0].tolist() == [[1, 2, 3], [6, 7, 8], [9, 9, 9]]
    assert pad.tolist() == [[False, True, True], [False, True, False], [False, True, True]]
    assert data.frames(np.array([0])) == 7
