"""Training data: split, relative and normalised action chunks, label flags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.errors import DemoError
from demo.store import EpisodeStore
from demo.training.config import for_policy
from demo.training.data import TrainingData, Windows, images_shuffled, prepare
from demo.policies.normalizer import MinMaxNormalizer
from demo.policies.policy import PolicySpec


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory, synthetic_store) -> Path:
    return synthetic_store(tmp_path_factory.mktemp("data") / "data.zarr")


def test_relative_actions_and_chunks_in_batches(data: Path) -> None:
    with EpisodeStore.open(data) as store:
        prepared = prepare(for_policy("bc", data=str(data), chunk=3, include_failures=True, val_fraction=0.0), store)
        raw, ends = store.load(["action", "obs.joint_pos"])
    windows = prepared.windows(prepared.train_episodes)
    t = np.array([0, 5, 29])  # 29 is the last frame of episode 0: chunk steps 1, 2 are padding
    obs, action, pad = windows.get(t)
    rel = prepared.action_norm.unnormalize(action.numpy())
    for row, frame in enumerate(t):
        for k in range(3):
            target = raw["action"][min(frame + k, 29)]
            assert np.allclose(rel[row, k, :2] + raw["obs.joint_pos"][frame], target[:2], atol=1e-5)
            assert rel[row, k, 2] == pytest.approx(target[2], abs=1e-5)
    assert pad[2].tolist() == [False, True, True]
    assert action.abs().max() <= 1.0 + 1e-5


def test_masks_choose_the_split(tmp_path: Path, synthetic_store) -> None:
    path = synthetic_store(tmp_path / "masked.zarr")
    with EpisodeStore.open(path, "a") as store:
        store.set_mask("val", np.arange(24) < 4)
        store.set_mask("keep", np.arange(24) < 12)
        prepared = prepare(for_policy("bc", val_mask="val", train_mask="keep", include_failures=True), store)
        assert prepared.val_episodes.tolist() == [0, 1, 2, 3]
        assert prepared.train_episodes.tolist() == list(range(4, 12))
        # Failed episodes (every 6th) are left out unless asked for; a seeded fraction is validation.
        default = prepare(for_policy("bc", seed=3), store)
        used = set(default.train_episodes) | set(default.val_episodes)
        assert used == {i for i in range(24) if i % 6 != 5} and len(default.val_episodes) == 2
        with pytest.raises(DemoError, match="no mask 'nope'"):
            prepare(for_policy("bc", val_mask="nope"), store)


def test_label_flags_choose_windows_and_pad_unlabelled_steps() -> None:
    n = 10
    labelled = np.array([1, 1, 0, 0, 1, 1, 1, 0, 1, 1], dtype=bool)
    unit = MinMaxNormalizer.from_limits(np.full(1, -1.0, np.float32), np.ones(1, np.float32))
    data = TrainingData(obs=np.arange(n, dtype=np.float32)[:, None], action=np.arange(n, dtype=np.float32)[:, None],
                        base=None, ends=np.array([n]), labelled=labelled, train_episodes=np.array([0]),
                        val_episodes=np.zeros(0, int), obs_spec=None, obs_norm=unit, action_norm=unit, relative=None,
                        spec=PolicySpec(1, 1, n_obs=1, horizon=3))
    windows = Windows(data, np.array([0]), normalize=False)
    assert windows.sampler.indices.tolist() == [0, 1, 4, 5, 6, 8, 9]
    obs, action, pad = windows.get(np.array([1, 6, 9]))
    assert action[:, :, 0].tolist() == [[1, 2, 3], [6, 7, 8], [9, 9, 9]]
    assert pad.tolist() == [[False, True, True], [False, True, False], [False, True, True]]
    assert data.frames(np.array([0])) == 7


def test_images_shuffled_moves_every_cameras_images_together_and_nothing_else() -> None:
    import torch

    n = 32
    state = torch.arange(n, dtype=torch.float32)[:, None, None].expand(n, 1, 3)
    images = {f"obs.image_{cam}": torch.arange(n)[:, None, None, None, None].expand(n, 1, 2, 2, 3) * k
              for k, cam in ((1, "front"), (2, "wrist"))}
    action, pad = torch.randn(n, 4, 2), torch.zeros(n, 4, dtype=torch.bool)
    obs, a, p = images_shuffled(({"state": state, **images}, action, pad), seed=0)
    order = obs["obs.image_front"][:, 0, 0, 0, 0]
    assert sorted(order.tolist()) == list(range(n)) and (order != torch.arange(n)).sum() > n // 2  # a permutation
    assert torch.equal(obs["obs.image_wrist"][:, 0, 0, 0, 0], 2 * order)  # the cameras stay together
    assert torch.equal(obs["state"], state) and a is action and p is pad  # the joints and labels stay put
    again, _, _ = images_shuffled(({"state": state, **images}, action, pad), seed=0)
    assert torch.equal(again["obs.image_front"], obs["obs.image_front"])  # drawn from the seed
    assert images_shuffled((state, action, pad), seed=0) is None  # a state policy has no cameras to check
    assert images_shuffled(({"state": state}, action, pad), seed=0) is None
