"""`demo bench peer-gail` (demo.experiments.peer_gail): the imitation library's GAIL as a peer of `demo irl train --algo gail`.

The GAIL runs need ``imitation`` and ``stable-baselines3``, which the project does not install: they skip
unless this interpreter is the peer's venv (README). The demonstrations' flattening and the refusals
need neither and run everywhere.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.experiments.peer_gail import INSTALL, PeerGailConfig, env_spec_for, load_demonstrations
from demo.seeds import eval_seeds
from demo.store import EpisodeStore
from demo.evaluation.evaluate import wilson_interval

try:
    import imitation  # noqa: F401
    import stable_baselines3  # noqa: F401

    HAVE_IMITATION = True
except ImportError:
    HAVE_IMITATION = False

needs_imitation = pytest.mark.skipif(not HAVE_IMITATION, reason="needs the imitation library (1.0.1) and "
                                     f"stable-baselines3, which demo does not install; run in their venv: {INSTALL}")
pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture(scope="module")
def reach_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.cli.main import main

    path = tmp_path_factory.mktemp("peer") / "reach.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "2", "--seed", "0", "--out", str(path)]) == 0
    return path


def test_demonstrations_are_what_the_flattened_env_observes_and_executes(reach_store: Path) -> None:
    """Replaying a demonstration's actions through the FlattenObservation env from its reset seed reproduces
    every stored (flattened) frame: same flattening, actions in the env's representation."""
    with EpisodeStore.open(reach_store) as store:
        spec = env_spec_for(store, str(reach_store), "reach")
        env = spec.make(training=True)
        try:
            demos = load_demonstrations(store, str(reach_store), env, None)
            horizon = env.unwrapped.horizon
            assert spec.options["action"] == store.meta.action.name == "joint_pos"
            assert len(demos.lengths) == 2 and demos.seeds == [int(s) for s in store.column("seed")]
            for obs, acts, n, seed in zip(demos.obs, demos.acts, demos.lengths, demos.seeds):
                assert obs.shape == (horizon + 1, env.observation_space.shape[0]) and acts.shape == (horizon, 8)
                assert n < horizon and (obs[n:] == obs[n - 1]).all() and (acts[n:] == acts[n - 1]).all()  # padding
                frame, _ = env.reset(seed=seed)
                assert np.array_equal(frame, obs[0])
                for t in range(n - 1):
                    frame, _, _, _, info = env.step(acts[t])
                    np.testing.assert_allclose(frame, obs[t + 1], atol=1e-6)
                _, _, _, _, info = env.step(acts[n - 1])
                assert info["success"]  # the demonstration ends with success held
        finally:
            env.close()
        with pytest.raises(Exception, match="pick"):
            env_spec_for(store, str(reach_store), "pick")


def test_bad_input_is_one_line(reach_store: Path, capsys: pytest.CaptureFixture) -> None:
    from demo.cli.main import main

    assert main(["bench", "peer-gail", "--data", str(reach_store), "--steps", "100", "--envs", "2",
                 "--rollout", "100"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--steps" in err[0] and "one GAIL round" in err[0]
    with pytest.raises(Exception, match="--demos"):
        PeerGailConfig(data=str(reach_store), demos=0).check()


@pytest.mark.skipif(HAVE_IMITATION, reason="checks the message given where imitation is missing")
def test_without_imitation_one_line_says_how_to_install(reach_store: Path, capsys: pytest.CaptureFixture) -> None:
    from demo.cli.main import main

    assert main(["bench", "peer-gail", "--data", str(reach_store), "--json", "-"]) != 0
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert out == "" and len(lines) == 1
    assert "imitation" in lines[0] and "pip install imitation==1.0.1" in lines[0]


@needs_imitation
def test_tiny_gail_writes_the_json_and_evaluates_on_demo_evals_episodes(reach_store: Path, tmp_path: Path) -> None:
    from demo.cli.main import main

    out = tmp_path / "peer.json"
    assert main(["bench", "peer-gail", "--data", str(reach_store), "--steps", "450", "--envs", "2", "--rollout", "100",
                 "--eval-episodes", "3", "--demo-batch-size", "64", "--seed", "3", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    # the evaluation: demo eval --seed 3 --episodes 3's reset seeds, as the env reported them
    assert r["eval"]["seeds"] == eval_seeds(3, 3)
    assert [e["seed"] for e in r["eval"]["episodes_detail"]] == eval_seeds(3, 3)
    assert r["eval"]["seed_overlap_with_data"] == 0 and r["training"]["seed_overlap_with_data"] == 0
    assert r["training"]["seed_overlap_with_eval"] == 0
    n, successes = r["eval_episodes"], r["successes"]
    assert n == 3 and successes == sum(e["success"] for e in r["eval"]["episodes_detail"])
    assert r["success_rate"] == successes / n and r["ci95"] == pytest.approx(list(wilson_interval(successes, n)))
    assert successes + sum(r["eval"]["failures"].values()) == n
    # steps: two whole rounds of 2 x 100 (450 is an upper bound), then the evaluation's
    assert r["training"]["rounds"] == 2 and r["train_env_steps"] == 400
    assert r["env_steps"] == 400 + sum(e["length"] for e in r["eval"]["episodes_detail"])
    assert [row["env_steps"] for row in r["training"]["per_round"]] == [200, 400]
    assert 0 < r["training"]["wall_s"] < r["wall_s"] and r["cpu_s"] > 0
    # the data, the env and what produced the numbers
    assert r["data"]["episodes"] == 2 and r["data"]["padded_transitions"] == 200
    assert r["observation"]["dim"] == sum(int(np.prod(s)) for s in _reach_shapes()) and r["action"]["name"] == "joint_pos"
    assert r["versions"]["imitation"] and r["versions"]["stable-baselines3"]
    assert r["hyperparameters"]["gail"]["demo_batch_size"] == 64 and "3_train_gail" in r["hyperparameters"]["source"]
    assert r["config"]["seed"] == 3 and r["env"]["env_id"] == "demo/Reach-v0"


@needs_imitation
def test_more_demonstrations_than_the_store_has_is_refused(reach_store: Path, capsys: pytest.CaptureFixture) -> None:
    from demo.cli.main import main

    assert main(["bench", "peer-gail", "--data", str(reach_store), "--demos", "5", "--steps", "200", "--envs", "2",
                 "--rollout", "100", "--demo-batch-size", "64"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--demos" in err[0] and "2 successful episodes" in err[0]


def _reach_shapes() -> list[tuple[int, ...]]:
    import gymnasium

    import demo.gym  # noqa: F401

    env = gymnasium.make("demo/Reach-v0")
    try:
        return [space.shape for space in env.observation_space.spaces.values()]
    finally:
        env.close()
