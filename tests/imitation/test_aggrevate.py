"""AggreVaTe: the cost-to-go from a saved simulator state is the expert's own rollout cost from there,
and each label is the cheapest candidate under it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from demo.sim import make_env
from demo.sim.rollout import run_expert
from demo.store import EpisodeStore
from demo.imitation.aggrevate import AggreVaTe, cost_to_go
from demo.training.config import TrainConfig
from demo.imitation.dagger import DaggerConfig, train_dagger
from demo.training.data import LABEL_KEY

torch.set_num_threads(1)
REACH = {"pos_tol": 0.04, "rot_tol": 0.4}


def test_cost_to_go_is_the_experts_rollout_cost_from_the_saved_state() -> None:
    env = make_env("reach", **REACH)
    seed = 11
    episode = run_expert(env, seed, np.random.default_rng([seed, 2]), hold_success_s=0.0, record=True)
    assert episode.success
    states, first = episode.data["sim.state"], episode.first_success_step
    for t in (0, first // 2, first - 1):
        cost, steps = cost_to_go(env, states[t], None, seed)
        # The expert from step t's state reaches success at the same step it did in the full episode
        # (its IK's warm start may move it by a step), and the steps spent are exactly those.
        assert abs(cost - (first - t)) <= 1 and steps == cost
        assert cost_to_go(env, states[t], None, seed) == (cost, steps)  # deterministic
    # A bad first action (every joint target 1 rad off) costs more than the expert's own.
    env.set_state(states[0])
    expert = env.expert(rng=np.random.default_rng([seed, 2]))
    good = np.asarray(expert.act(env), np.float32)
    bad = good.copy()
    bad[:7] += 1.0
    assert cost_to_go(env, states[0], bad, seed)[0] > cost_to_go(env, states[0], good, seed)[0]
    # Not reaching success before the horizon costs the steps left plus failure_cost: the start
    # state with the clock (the state's first entry, s) two control steps before the horizon.
    late = states[0].copy()
    late[0] = (env.horizon - 2) / env.fps
    assert cost_to_go(env, late, None, seed, failure_cost=1000.0) == (1002.0, 2)


@pytest.mark.slow
def test_aggrevate_labels_are_the_cheapest_candidate(reach_demos, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(reach_demos(8)), out=str(tmp_path / "run"), steps=100, batch_size=64,
                     policy={"hidden": (32, 32)}, val_fraction=0.25, log_every=50, val_every=50)
    family = AggreVaTe(states=3, candidates=3, sigma=0.3)
    summary = train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=2, round_steps=40), family=family)
    assert summary["algo"] == "aggrevate"
    entry = summary["rounds"][1]
    assert entry["sim_steps"] > 0 and entry["rollin_steps"] > 0
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    env = make_env("reach", **REACH)
    checked = 0
    for i in np.flatnonzero(store.column("dagger_round") == 1):
        ep = store.read_episode(int(i))
        flags = ep[LABEL_KEY].astype(bool)
        assert 1 <= flags.sum() <= 3 and int(store.column("labels")[i]) == int(flags.sum())
        seed = int(store.column("seed")[i])
        for t in np.flatnonzero(flags):
            state = ep["sim.state"][t]
            env.set_state(state)
            own = np.asarray(env.expert(rng=np.random.default_rng([seed, 2])).act(env), np.float32)
            # No candidate the expert's action competed with beats the stored label.
            assert cost_to_go(env, state, ep["action"][t], seed)[0] <= cost_to_go(env, state, own, seed)[0]
            checked += 1
    assert checked == entry["labels_round"]
