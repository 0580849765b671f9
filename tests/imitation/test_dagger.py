"""DAgger on reach: visited states are aggregated with the expert's labels, and labels are counted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.errors import DemoError
from demo.sim import make_env
from demo.store import EpisodeStore
from demo.training.config import TrainConfig
from demo.training.data import LABEL_KEY, frame_indices, prepare
from demo.imitation.dagger import DaggerConfig, train_dagger

torch.set_num_threads(1)
REACH = {"pos_tol": 0.04, "rot_tol": 0.4}


@pytest.fixture(scope="module")
def demos(reach_demos) -> Path:
    return reach_demos(8)  # read-only: DAgger copies its source


def dagger(demos: Path, out: Path, **kw) -> dict:
    tc = TrainConfig(data=str(demos), out=str(out), steps=150, batch_size=64, chunk=2, policy={"hidden": (64, 64)},
                     val_fraction=0.25, log_every=50, val_every=50)
    # Single-step labels (each visited state's action) unless a test asks for chunk labels.
    config = DaggerConfig(train=tc, rounds=2, episodes_per_round=2, round_steps=60, **{"chunk_labels": False, **kw})
    return train_dagger(config)


@pytest.mark.slow
def test_dagger_aggregates_expert_labelled_states(demos: Path, tmp_path: Path) -> None:
    summary = dagger(demos, tmp_path / "run")
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    with EpisodeStore.open(demos) as source:
        assert store.num_episodes == source.num_episodes + 4  # the source is copied, never modified
        demo_frames = source.num_frames
    rounds = store.column("dagger_round")
    assert rounds.tolist() == [0] * 8 + [1, 1, 2, 2]
    assert store.column("source")[8:].tolist() == ["dagger"] * 4
    new = np.flatnonzero(rounds >= 1)
    lengths = store.episode_lengths[new]
    # Plain DAgger: every visited state is a label; the count is demos (train + val) + rollout frames.
    assert store.column("labels")[new].tolist() == lengths.tolist()
    assert summary["expert_labels"] == demo_frames + int(lengths.sum())
    assert [r["labels_total"] for r in summary["rounds"]] == [
        demo_frames, demo_frames + int(lengths[:2].sum()), demo_frames + int(lengths.sum())]
    # Each label is what the expert does in that recorded state (it is a state-feedback policy; its IK
    # warm start makes a re-query differ by a few mrad), not what the learner executed there.
    env = make_env("reach", **REACH)
    for i in new[:2]:
        ep = store.read_episode(int(i))
        assert ep[LABEL_KEY].all()
        expert = env.expert()
        for t in (0, len(ep["action"]) // 2, len(ep["action"]) - 1):
            env.set_state(ep["sim.state"][t])
            assert np.abs(expert.act(env) - ep["action"][t]).max() < 0.02
    # With beta = 0 the learner drives: what was executed is not the label.
    ep = store.read_episode(int(new[0]))
    assert not np.allclose(ep["info.executed_action"], ep["action"], atol=1e-3)
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert run["algo"] == "dagger" and run["data"]["expert_labels"] == summary["expert_labels"]
    assert (tmp_path / "run" / "policy.safetensors").exists() and (tmp_path / "run" / "curves.png").exists()


@pytest.mark.slow
def test_beta_one_executes_the_expert(demos: Path, tmp_path: Path) -> None:
    dagger(demos, tmp_path / "run", beta="linear:1000000")
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    for i in np.flatnonzero(store.column("dagger_round") >= 1):
        ep = store.read_episode(int(i))
        assert np.allclose(ep["info.executed_action"], ep["action"])


@pytest.mark.slow
def test_hg_dagger_labels_only_interventions(demos: Path, tmp_path: Path) -> None:
    summary = dagger(demos, tmp_path / "run", gate="deviation:0.06")
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    new = np.flatnonzero(store.column("dagger_round") >= 1)
    total = 0
    for i in new:
        ep = store.read_episode(int(i))
        flags = ep[LABEL_KEY].astype(bool)
        total += int(flags.sum())
        assert int(store.column("labels")[i]) == int(flags.sum())
        # The expert executed exactly where it labelled.
        same = np.all(np.isclose(ep["info.executed_action"], ep["action"]), axis=1)
        assert np.array_equal(same, flags)
    assert 0 < total < store.episode_lengths[new].sum()
    with EpisodeStore.open(demos) as source:
        assert summary["expert_labels"] == source.num_frames + total


def test_bad_schedules_and_tasks_fail_clearly(demos: Path, tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="--beta"):
        dagger(demos, tmp_path / "a", beta="cosine:3")
    with pytest.raises(DemoError, match="--gate"):
        dagger(demos, tmp_path / "b", gate="deviation:-1")
    with pytest.raises(DemoError, match="holds 'reach' demonstrations"):
        dagger(demos, tmp_path / "c", task="pick")


@pytest.mark.slow
def test_rounds_keep_the_demonstrations_normalisers_unless_refit(demos: Path, tmp_path: Path) -> None:
    """An early learner's flailing rollouts must not stretch the input ranges the states that matter live in."""
    from demo.policies.checkpoint import load_bundle

    dagger(demos, tmp_path / "keep")
    dagger(demos, tmp_path / "refit", refit_normalizers=True)
    keep, refit = load_bundle(tmp_path / "keep"), load_bundle(tmp_path / "refit")
    store = EpisodeStore.open(tmp_path / "keep" / "data.zarr")
    rounds = store.column("dagger_round")
    tc = TrainConfig(data=str(tmp_path / "keep" / "data.zarr"), out="", val_fraction=0.25).resolved()
    s0 = prepare(tc, store, among=np.flatnonzero(rounds == 0))
    np.testing.assert_array_equal(keep.obs_norm.low, s0.obs_norm.low)
    np.testing.assert_array_equal(keep.obs_norm.high, s0.obs_norm.high)
    # Refit: the ranges are those of every training frame of the aggregate, rollouts included.
    from demo.policies.normalizer import MinMaxNormalizer

    agg = EpisodeStore.open(tmp_path / "refit" / "data.zarr")
    obs = s0.obs_spec.concat(agg.load(s0.obs_spec.source_keys)[0])
    train_eps = np.union1d(s0.train_episodes, np.flatnonzero(agg.column("dagger_round") >= 1))
    fitted = MinMaxNormalizer.fit(obs[frame_indices(agg.episode_ends, train_eps)])
    np.testing.assert_allclose(refit.obs_norm.low, fitted.low, atol=1e-6)
    assert (fitted.low < keep.obs_norm.low - 1e-3).any()  # the rollouts did leave the demonstrations' ranges


def test_gripper_disagreement_opens_the_hg_dagger_gate() -> None:
    """A learner that moves the arm as the expert does but leaves the gripper wrong is taken over."""
    from demo.imitation.dagger import ActionParts, dagger_episode

    env = make_env("reach", **REACH)

    class ArmOnly:  # the expert's arm targets, the opposite gripper command
        def reset(self, seed: int, env_: object) -> None:
            self.expert = env.expert()

        def act(self, frame: dict) -> np.ndarray:
            a = np.asarray(self.expert.act(env), dtype=np.float32).copy()
            a[-1] = 1.0 - a[-1]
            return a

    data, info = dagger_episode(env, ArmOnly(), seed=5, beta=0.0, gate=0.05, parts=ActionParts.of(env))
    flags = data[LABEL_KEY].astype(bool)
    assert flags.all() and info["labels"] == len(flags)


@pytest.mark.slow
def test_resume_adds_rounds_from_the_runs_own_copy(demos: Path, tmp_path: Path) -> None:
    """A resumed run needs only its directory: the source store may be gone."""
    import shutil

    source = tmp_path / "source.zarr"
    shutil.copytree(demos, source)
    tc = TrainConfig(data=str(source), out=str(tmp_path / "run"), steps=60, batch_size=64, policy={"hidden": (32,)},
                     val_fraction=0.25, log_every=20, val_every=20)
    train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=1, round_steps=20))
    shutil.rmtree(source)
    summary = train_dagger(DaggerConfig(train=tc, rounds=2, episodes_per_round=1, round_steps=20), resume=True)
    assert [r["round"] for r in summary["rounds"]] == [0, 1, 2] and summary["step"] == 60 + 2 * 20
    from demo.imitation.dagger import SEGMENT_SOURCE

    with EpisodeStore.open(tmp_path / "run" / "data.zarr") as store:
        rounds, rollouts = store.column("dagger_round"), store.column("source") != SEGMENT_SOURCE
        assert rounds[rollouts].tolist() == [0] * 8 + [1, 2]
        assert set(rounds[~rollouts].tolist()) == {1, 2}  # each round's segments (the default labels) beside its rollout
        episodes = store.num_episodes
    # DAgger's own settings shape the aggregate: resuming with other labels or a gate is refused, nothing written
    for changed in ({"segment_labels": False}, {"gate": "deviation:0.05"}, {"beta": "indicator"}):
        with pytest.raises(DemoError, match=f"cannot resume with a different .*{next(iter(changed))}"):
            train_dagger(DaggerConfig(train=tc, rounds=3, episodes_per_round=1, round_steps=20, **changed), resume=True)
    # told what the first start resolved by itself (segments, normalisers refit): the same run, which goes on
    summary = train_dagger(DaggerConfig(train=tc, rounds=3, episodes_per_round=1, round_steps=20, chunk_labels=True,
                                        refit_normalizers=True), resume=True)
    assert [r["round"] for r in summary["rounds"]] == [0, 1, 2, 3]
    with EpisodeStore.open(tmp_path / "run" / "data.zarr") as store:
        assert store.num_episodes > episodes


class Sluggish:
    """Half the expert's motion: a learner that lags, so the states it visits leave the expert's path."""

    def __init__(self, env) -> None:
        self.env = env

    def reset(self, seed: int, env_: object) -> None:
        self.expert = self.env.expert()

    def act(self, frame: dict) -> np.ndarray:
        a = np.asarray(self.expert.act(self.env), dtype=np.float32).copy()
        a[:-1] = 0.5 * (a[:-1] + frame["obs.joint_pos"])
        return a


def test_chunk_labels_are_the_experts_own_plan_and_change_nothing_else() -> None:
    """A chunked learner's labels (ChunkLabels): the chunk at a visited state is what the expert executes from
    there (at the reset state: the start of the expert's own episode), one every ``stride`` steps, each of its
    actions counted; looking ahead leaves the rollout exactly as it was."""
    from demo.imitation.dagger import ActionParts, ChunkLabels, dagger_episode
    from demo.sim.rollout import run_expert
    from demo.training.data import CHUNK_KEY, HAS_CHUNK_KEY

    env = make_env("pick")

    parts = ActionParts.of(env)
    plain, _ = dagger_episode(env, Sluggish(env), seed=7, beta=0.0, gate=None, parts=parts)
    data, info = dagger_episode(env, Sluggish(env), seed=7, beta=0.0, gate=None, parts=parts, chunks=ChunkLabels(8, 4))
    for key in set(plain) - {LABEL_KEY}:  # the same rollout, bit for bit; the labels are the difference
        np.testing.assert_array_equal(plain[key], data[key], err_msg=key)
    has = data[HAS_CHUNK_KEY].astype(bool)
    assert np.array_equal(np.flatnonzero(has), np.arange(0, len(has), 4)) and np.array_equal(has, data[LABEL_KEY] == 1)
    assert info["labels"] == 8 * int(has.sum())
    chunks = data[CHUNK_KEY]
    np.testing.assert_array_equal(chunks[has, 0], data["action"][has])  # its first action is the step's label
    expert = run_expert(env, 7, rng=np.random.default_rng([7, 2]), record=True)
    np.testing.assert_allclose(chunks[0], expert.data["action"][:8], atol=1e-6)
    assert np.abs(chunks[8] - chunks[4]).max() > 0  # states differ: so do their plans


def test_segment_labels_keep_the_experts_look_ahead_whole() -> None:
    """Segment labels (ChunkLabels.segments): at a labelled state the expert's look-ahead is recorded as an
    episode of its own, its frames the states the expert's own actions lead to and its actions the same as the
    chunk label from there; the rollout itself is unchanged, holds no labels on its frames, and pays for its
    segments' actions."""
    from demo.imitation.dagger import SEGMENT_SOURCE, ActionParts, ChunkLabels, dagger_episode
    from demo.sim.rollout import run_expert

    env = make_env("pick")

    parts = ActionParts.of(env)
    plain, _ = dagger_episode(env, Sluggish(env), seed=7, beta=0.0, gate=None, parts=parts)
    data, info = dagger_episode(env, Sluggish(env), seed=7, beta=0.0, gate=None, parts=parts,
                                chunks=ChunkLabels(8, 4, segments=True))
    for key in set(plain) - {LABEL_KEY}:  # the same rollout, bit for bit
        np.testing.assert_array_equal(plain[key], data[key], err_msg=key)
    assert not data[LABEL_KEY].any()
    segments = info["segments"]
    n = len(plain["action"])
    assert len(segments) == (n + 3) // 4 and info["labels"] == 8 * len(segments)
    for k, (frames, row) in enumerate(segments):
        assert len(frames["action"]) == 8 and frames[LABEL_KEY].all() and frames["info.intervention"].all()
        assert row["source"] == SEGMENT_SOURCE and row["labels"] == 0 and row["seed"] == 7
        np.testing.assert_array_equal(frames["sim.state"][0], data["sim.state"][4 * k])  # starts where the learner was
        np.testing.assert_array_equal(frames["action"][0], data["action"][4 * k])  # with the step's own label
    expert = run_expert(env, 7, rng=np.random.default_rng([7, 2]), record=True)
    first = segments[0][0]  # from the reset state: the start of the expert's own episode, states and actions
    np.testing.assert_allclose(first["action"], expert.data["action"][:8], atol=1e-6)
    np.testing.assert_allclose(first["obs.joint_pos"], expert.data["obs.joint_pos"][:8], atol=1e-6)


def test_segment_labels_train_a_window_at_every_segment_state(demos: Path, tmp_path: Path) -> None:
    """End to end: the segments are stored beside their rollout in one round, the budget counts their actions
    once, and each of a segment's states starts a training window on the segment's own next actions."""
    from demo.imitation.config import learner_config
    from demo.imitation.dagger import SEGMENT_SOURCE

    summary = dagger(demos, tmp_path / "run", chunk_labels=True, label_stride=3)  # segments: the default
    with EpisodeStore.open(tmp_path / "run" / "data.zarr") as store:
        rounds, source = store.column("dagger_round"), store.column("source")
        rollouts = np.flatnonzero((rounds >= 1) & (source != SEGMENT_SOURCE))
        segments = np.flatnonzero(source == SEGMENT_SOURCE)
        assert len(rollouts) == 4 and len(segments) > 0 and set(rounds[segments]) == {1, 2}
        assert store.column("labels")[segments].sum() == 0
        assert store.column("labels")[rollouts].sum() == store.episode_lengths[segments].sum()
        assert not store.read_episode(int(rollouts[0]))[LABEL_KEY].any()
        data = prepare(learner_config(data=str(tmp_path / "run" / "data.zarr"), chunk=2, val_fraction=0.25), store)
        seg = store.read_episode(int(segments[0]))
        start = int(store.column("start")[segments[0]])
    assert summary["expert_labels"] == summary["rounds"][0]["labels_total"] + int(store.episode_lengths[segments].sum())
    windows = data.windows(np.array([int(segments[0])]))
    assert len(windows) == len(seg["action"])  # a window at every state of the segment
    _, target, pad = windows.get(np.array([start]))
    chunk = data.action_norm.unnormalize(target.numpy())
    if data.base is not None:
        chunk = chunk + data.base[[start]][:, None, :]
    np.testing.assert_allclose(chunk[0], seg["action"][:2], atol=1e-5)
    assert not pad.numpy().any()


def test_a_chunked_learner_trains_on_chunk_labels(demos: Path, tmp_path: Path) -> None:
    """End to end: the aggregate holds the chunk labels, the budget counts every labelled action, and the
    learner's training windows at a labelled rollout state are its chunk label."""
    from demo.imitation.config import learner_config
    from demo.training.data import CHUNK_KEY, HAS_CHUNK_KEY

    summary = dagger(demos, tmp_path / "run", chunk_labels=True, segment_labels=False, label_stride=3)
    with EpisodeStore.open(tmp_path / "run" / "data.zarr") as store:
        rollouts = np.flatnonzero(store.column("dagger_round") >= 1)
        ep = store.read_episode(int(rollouts[0]))
        has = ep[HAS_CHUNK_KEY].astype(bool)
        assert np.array_equal(np.flatnonzero(has), np.arange(0, len(has), 3))
        assert store.column("labels")[rollouts[0]] == 2 * has.sum()  # chunk 2: two actions a label
        data = prepare(learner_config(data=str(tmp_path / "run" / "data.zarr"), chunk=2, val_fraction=0.25), store)
    assert summary["rounds"][-1]["labels_total"] == summary["rounds"][0]["labels_total"] + int(
        store.column("labels")[rollouts].sum())
    start = int(store.column("start")[rollouts[0]])
    t = start + np.flatnonzero(has)[:2]
    windows = data.windows(np.array([int(rollouts[0])]))
    _, target, pad = windows.get(t)
    chunk = data.action_norm.unnormalize(target.numpy())
    if data.base is not None:  # relative actions: to the query frame's state
        chunk = chunk + data.base[t][:, None, :]
    np.testing.assert_allclose(chunk, ep[CHUNK_KEY][has][:2], atol=1e-5)
    assert not pad.numpy().any()


def test_normalisers_are_refit_where_the_labelled_frames_are_the_experts() -> None:
    """Unless told: refit with segment labels (the labelled frames are the expert's own states), keep the
    demonstrations' ranges elsewhere (under a gate, or with labels on the learner's own frames)."""
    def config(chunk: int = 16, **kw) -> DaggerConfig:
        return DaggerConfig(train=TrainConfig(chunk=chunk), **kw)

    assert config().uses_segment_labels() and config().refits_normalizers()
    assert not config(chunk=1).refits_normalizers()  # a single-step learner's labels are the visited states'
    assert not config(gate="deviation:0.05").refits_normalizers()
    assert not config(segment_labels=False).refits_normalizers()
    assert not config(chunk_labels=False).uses_segment_labels()
    assert not config(refit_normalizers=False).refits_normalizers()
    assert config(gate="deviation:0.05", refit_normalizers=True).refits_normalizers()
