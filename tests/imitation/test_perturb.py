"""State perturbation: perturbed states carry what is held and get the expert's label *there*."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from demo.sim import make_env
from demo.sim.geometry import quat_to_mat
from demo.sim.rollout import run_expert
from demo.store import EpisodeStore
from demo.training.config import TrainConfig
from demo.imitation.dagger import DaggerConfig, train_dagger
from demo.imitation.perturb import Perturb, held_joints, perturb_state

torch.set_num_threads(1)
REACH = {"pos_tol": 0.04, "rot_tol": 0.4}


def test_perturbed_states_get_their_own_expert_labels() -> None:
    env = make_env("reach", **REACH)
    episode = run_expert(env, 3, np.random.default_rng([3, 2]), record=True)
    state = episode.data["sim.state"][20]
    env.set_state(state)
    expert = env.expert(rng=np.random.default_rng([3, 2]))
    clean = np.asarray(expert.act(env), np.float32)
    q0 = env.data.qpos[env.arm_qadr].copy()
    assert perturb_state(env, np.random.default_rng(0), 0.05)
    moved = env.data.qpos[env.arm_qadr] - q0
    assert 0.01 < np.abs(moved).max() < 0.3
    label = np.asarray(expert.act(env), np.float32)
    # The expert answers for the perturbed state: its targets move with the displaced joints.
    assert np.abs(label[:7] - clean[:7]).max() > 0.01
    env.set_state(state)
    np.testing.assert_allclose(np.asarray(expert.act(env), np.float32), clean, atol=0.02)


def test_a_held_cube_moves_with_the_hand() -> None:
    env = make_env("pick")
    episode = run_expert(env, 0, np.random.default_rng([0, 2]), record=True)
    states = episode.data["sim.state"]
    lifted = None
    for t in range(len(states)):  # the first step with the cube in the fingers, 5 cm up
        env.set_state(states[t])
        if held_joints(env) and env.data.qpos[held_joints(env)[0] + 2] > 0.05:
            lifted = t
            break
    assert lifted is not None
    env.set_state(states[lifted])
    (adr,) = held_joints(env)
    site = env.ee_site

    def in_hand() -> tuple[np.ndarray, np.ndarray]:
        pos, rot = env.data.site_xpos[site], env.data.site_xmat[site].reshape(3, 3)
        return rot.T @ (env.data.qpos[adr : adr + 3] - pos), rot.T @ quat_to_mat(env.data.qpos[adr + 3 : adr + 7])

    p0, r0 = in_hand()
    cube0 = env.data.qpos[adr : adr + 3].copy()
    rng = np.random.default_rng(1)
    while not perturb_state(env, rng, 0.03):
        env.set_state(states[lifted])
    p1, r1 = in_hand()
    np.testing.assert_allclose(p1, p0, atol=1e-6)
    np.testing.assert_allclose(r1, r0, atol=1e-6)
    assert np.linalg.norm(env.data.qpos[adr : adr + 3] - cube0) > 1e-3  # the cube did move, with the hand


def test_perturb_rounds_record_expert_labels_of_perturbed_states(reach_demos, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(reach_demos(8)), out=str(tmp_path / "run"), steps=40, batch_size=32,
                     policy={"hidden": (16,)}, log_every=20, val_every=20)
    summary = train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=1, round_steps=20), family=Perturb(sigma=0.05))
    assert summary["algo"] == "perturb"
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    (i,) = np.flatnonzero(store.column("dagger_round") == 1)
    ep = store.read_episode(int(i))
    assert store.column("source")[i] == "perturb" and ep["info.labelled"].all()
    env = make_env("reach", **REACH)
    seed = int(store.column("seed")[i])
    clean = run_expert(env, seed, np.random.default_rng([seed, 2]), record=True).data
    n = min(len(clean["action"]), len(ep["action"]))
    # Recorded states are not the clean trajectory's, and each label is the expert's at its own state.
    assert np.abs(ep["obs.joint_pos"][:n] - clean["obs.joint_pos"][:n]).max(axis=1).min() > 1e-4
    for t in (0, n // 2, n - 1):
        env.set_state(ep["sim.state"][t])
        label = np.asarray(env.expert(rng=np.random.default_rng([seed, 2])).act(env), np.float32)
        np.testing.assert_allclose(label, ep["action"][t], atol=0.02)
