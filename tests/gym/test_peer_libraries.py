"""``demo/Pick-v0`` used from stable-baselines3 and the ``imitation`` library as their users use them, with no
wrapper of the user's own: SB3's env checker and PPO; the expert as an SB3/imitation policy over a vectorised
env (:class:`demo.gym.ObservationExpert`); a store's episodes as ``imitation`` trajectories, final
observations included (:mod:`demo.gym.trajectories`), trained on by imitation's BC.

Both libraries are optional peers that ``demo`` does not install (imitation 1.0.1 pins gymnasium 0.29):
these tests skip unless this interpreter has them, e.g. the peer venv of the README's peer GAIL,
``python3 -m venv ../venv-imitation && ../venv-imitation/bin/pip install -e . pytest &&
../venv-imitation/bin/pip install imitation==1.0.1``, then ``../venv-imitation/bin/pytest
tests/gym/test_peer_libraries.py`` (its ``pytest``, not ``python -m pytest``, which puts the repository root,
and so its ``imitation/`` folder, ahead of the library).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import demo.gym
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.gym.trajectories import trajectories
from demo.seeds import episode_seed
from demo.store import EpisodeStore

sb3 = pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (a peer library; see this "
                                                      "file's docstring for its venv)")
imitation = pytest.importorskip("imitation", reason="the imitation library is not installed (a peer library; see "
                                                    "this file's docstring for its venv)")
if Path(imitation.__file__).resolve().parent == Path(demo.gym.__file__).resolve().parents[1] / "imitation":
    pytest.skip("`imitation` is demo's own imitation/ folder: run the peer venv's pytest, not python -m pytest "
                "(this file's docstring)", allow_module_level=True)
from imitation.algorithms import bc  # noqa: E402
from imitation.data import rollout, types  # noqa: E402
from imitation.data.wrappers import RolloutInfoWrapper  # noqa: E402
from stable_baselines3.common.env_checker import check_env  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

pytestmark = pytest.mark.usefixtures("torch_one_thread")
PICK = demo.gym.env_id("pick")


def test_sb3_checks_the_env_and_ppo_learns_on_it() -> None:
    env = gymnasium.make(PICK, normalize_actions=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert [str(w.message) for w in caught] == []  # bounds, shapes, dtypes, normalised actions: nothing to say
    model = sb3.PPO("MultiInputPolicy", DummyVecEnv([lambda: gymnasium.make(PICK, normalize_actions=True)] * 2),
                    n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=256)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    assert env.action_space.contains(action)
    env.close()


def test_the_expert_is_a_policy_of_observations_over_a_vectorised_env() -> None:
    """imitation's own rollout collector drives the expert over two envs: every episode succeeds, as the
    privileged expert's do."""
    venv = DummyVecEnv([lambda: RolloutInfoWrapper(gymnasium.make(PICK, sim_state=True))] * 2)
    venv.seed(episode_seed(0, 0))
    probe = gymnasium.make(PICK, sim_state=True)
    expert = probe.unwrapped.expert_policy()
    trajs = rollout.generate_trajectories(expert, venv, rollout.make_min_episodes(6), rng=np.random.default_rng(0))
    assert len(trajs) >= 6
    assert all(t.terminal and t.infos[-1]["success"] for t in trajs)
    # An SB3 policy object too: predict on a batch.
    actions, _ = expert.predict(venv.reset())
    assert actions.shape == (2, 8) and actions.dtype == np.float32
    expert.close()
    probe.close()
    venv.close()


def test_imitation_bc_trains_on_a_stores_trajectories(tmp_path: Path) -> None:
    store_path = tmp_path / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=8, seed=0), store_path, workers=0)
    env = gymnasium.make(PICK, normalize_actions=True)
    with EpisodeStore.open(store_path) as store:
        ours = list(trajectories(store, env))
    demos = [types.Trajectory(obs=types.DictObs(t.obs), acts=t.actions, infos=None, terminal=t.terminal)
             for t in ours]
    assert all(len(d.obs) == len(d.acts) + 1 for d in demos)
    learner = bc.BC(observation_space=env.observation_space, action_space=env.action_space, demonstrations=demos,
                    rng=np.random.default_rng(0), device="cpu", batch_size=64)
    seen = {k: np.concatenate([t.obs[k][:-1] for t in ours]) for k in ours[0].obs}  # the states acted in
    taken = np.concatenate([t.actions for t in ours])

    def mse() -> float:
        acts, _ = learner.policy.predict(seen, deterministic=True)
        return float(np.mean((acts - taken) ** 2))

    before = mse()
    learner.train(n_epochs=30)
    assert mse() < 0.5 * before
    env.close()
