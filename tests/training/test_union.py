"""One policy on several stores (`demo train A B`): what a union may hold, what its run records, and
which robots its policy may be evaluated on (`demo eval RUN --robot`).

The second arm is the built-in Panda under another name (a config of our own pointing at its MJCF), so
every test runs without third-party packages; the 6-DOF refusal runs on synthetic stores."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.evaluation.evaluate import EvalConfig, evaluate
from demo.sim.robot import ASSETS, BUILTIN_CONFIG
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.training.config import for_policy
from demo.training.data import open_stores, prepare_union

REACH_KEYS = ("obs.ee_pos", "obs.ee_quat", "obs.gripper", "obs.goal_pos", "obs.goal_quat")  # reach's robot-agnostic ones
AGNOSTIC = ",".join(REACH_KEYS)
TINY = ["--steps", "40", "--batch-size", "32", "--chunk", "4", "--policy-opt", "hidden=32,32"]


def twin_config(folder: Path, name: str) -> Path:
    """The built-in arm's config under another robot name (a non-built-in robot: recorded with its files)."""
    text = BUILTIN_CONFIG.read_text().replace('name = "panda_prim"', f'name = "{name}"')
    text = text.replace('mjcf = "panda.xml"', f'mjcf = "{(ASSETS / "panda.xml").as_posix()}"')
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def arms(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """reach on the built-in arm and on its twin (3 episodes each), joint_pos and ee7."""
    d = tmp_path_factory.mktemp("union")
    twin = twin_config(d, "panda_twin")
    other = twin_config(d, "panda_other")  # the twin's arm on another base: another arm by content
    other.write_text(other.read_text() + "base_pos = [0.02, 0.0, 0.0]\n")
    paths = {"twin_toml": twin, "other_toml": other, "renamed_toml": twin_config(d, "panda_renamed")}
    for name, robot in (("builtin", None), ("twin", str(twin))):
        assert main(["collect", "--task", "reach", "--episodes", "3", "--seed", "0", "--out", str(d / f"{name}.zarr"),
                     *(["--robot", robot] if robot else [])]) == 0
        assert main(["convert", str(d / f"{name}.zarr"), "--to", "ee7", "--out", str(d / f"{name}_ee7.zarr")]) == 0
        paths[name], paths[f"{name}_ee7"] = d / f"{name}.zarr", d / f"{name}_ee7.zarr"
    return paths


@pytest.fixture(scope="module")
def union_run(arms: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("union_run") / "run"
    assert main(["train", str(arms["builtin_ee7"]), str(arms["twin_ee7"]), "--out", str(out), "--obs-keys", AGNOSTIC,
                 "--val-fraction", "0", *TINY]) == 0
    return out


def test_union_trains_on_both_stores_and_records_both_robots(union_run: Path, arms: dict[str, Path]) -> None:
    run = json.loads((union_run / "run.json").read_text())
    assert [r["name"] for r in run["robots"]] == ["panda_prim", "panda_twin"]
    assert run["robot"]["name"] == "panda_prim"
    stores = run["data"]["stores"]
    assert [Path(s["path"]) for s in stores] == [arms["builtin_ee7"].resolve(), arms["twin_ee7"].resolve()]
    assert [(s["first_episode"], s["episodes"], s["train_episodes"], s["robot"]) for s in stores] == \
        [(0, 3, 3, "panda_prim"), (3, 3, 3, "panda_twin")]
    assert run["data"]["train_episodes"] == [0, 1, 2, 3, 4, 5]
    frames = sum(EpisodeStore.open(p).episode_lengths.sum() for p in (arms["builtin_ee7"], arms["twin_ee7"]))
    assert run["data"]["train_frames"] == frames
    assert run["train"]["data"] == [str(arms["builtin_ee7"]), str(arms["twin_ee7"])]
    # The twin's files travel with the run (the built-in arm has none), away from the first robot's folder.
    assert (union_run / "robots" / "1" / "robot" / "panda.xml").is_file() and not (union_run / "robot").exists()


def test_union_concatenates_store_after_store(arms: dict[str, Path]) -> None:
    config = for_policy("bc", data=(str(arms["builtin_ee7"]), str(arms["twin_ee7"])), out="unused", chunk=4,
                        obs_keys=REACH_KEYS, val_fraction=0.0)
    with open_stores(config.stores) as stores:
        data = prepare_union(config, stores)
        one = prepare_union(config, stores[:1])
    n = int(one.ends[-1])
    assert len(data.ends) == 6 and data.ends[2] == n and len(data.obs) == data.ends[-1] == 2 * n
    np.testing.assert_array_equal(data.ends[3:], one.ends + n)  # the twin repeats the built-in arm's demos
    np.testing.assert_array_equal(data.action[n:], one.action)
    assert [(s.first_episode, s.episodes) for s in data.sources] == [(0, 3), (3, 3)]


def test_eval_on_the_second_arm_by_name(union_run: Path, tmp_path: Path) -> None:
    js = tmp_path / "eval.json"
    assert main(["eval", str(union_run), "--robot", "panda_twin", "--episodes", "1", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    assert result["robot"] == "panda_twin" and result["robot_trained_on"] is True and result["episodes"] == 1


def test_ee7_policy_may_run_on_a_robot_it_was_not_trained_on(union_run: Path, arms: dict[str, Path], tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """It runs there; a policy that succeeds on no episode of a robot it was not trained on exits non-zero after its
    results are written (the tiny run succeeds nowhere); on the robot it was trained on, 0% is a result (exit 0)."""
    js = tmp_path / "eval.json"
    argv = ["eval", str(union_run), "--robot", str(arms["other_toml"]), "--episodes", "2", "--json", str(js)]
    result = evaluate(EvalConfig(run=str(union_run), robot=str(arms["other_toml"]), episodes=2))
    assert result["robot"] == "panda_other" and result["robot_trained_on"] is False
    assert "not among the robots the policy was trained on" in result["robot_note"]
    assert result["successes"] == 0  # a few training steps: it cannot do the task yet
    assert_fails_after_results(capsys, argv, str(union_run), "succeeded on none of 2 episodes on robot 'panda_other'",
                               "not trained on")
    assert json.loads(js.read_text())["robot_trained_on"] is False  # written before the verdict
    # The twin under another name is the arm it was trained on: identity is the content, the name a label; its 0%
    # is a result (exit 0), unless --min-success asks for more.
    twin = ["eval", str(union_run), "--robot", str(arms["renamed_toml"]), "--episodes", "1", "--json", str(js)]
    assert main(twin) == 0
    assert json.loads(js.read_text())["robot_trained_on"] is True
    assert_fails_after_results(capsys, [*twin, "--min-success", "0.5"], str(union_run), "success 0.00 < --min-success 0.5")


def assert_fails_after_results(capsys: pytest.CaptureFixture[str], argv: list[str], *needles: str) -> None:
    """``demo ARGV`` shows its results (table, JSON) and then fails: exit code 1, its last line one error holding
    every needle."""
    capsys.readouterr()
    assert main(argv) == 1
    captured = capsys.readouterr()
    last = captured.err.strip().splitlines()[-1]
    assert last.startswith("error: ") and all(n in last for n in needles), captured.err
    assert "evaluated" in captured.out and "Traceback" not in captured.err


def test_joint_policy_refuses_another_robot(arms: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "joint"
    assert main(["train", str(arms["builtin"]), "--out", str(out), *TINY]) == 0
    capsys.readouterr()
    assert main(["eval", str(out), "--robot", str(arms["twin_toml"]), "--episodes", "1"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "was trained on robot 'panda_prim'; it cannot be evaluated on 'panda_twin'" in err[0]
    assert "joint targets" in err[0] and "--to ee7" in err[0]


def test_joint_union_of_the_same_joints_trains(arms: dict[str, Path], tmp_path: Path) -> None:
    """Two arms with the very same joints may share joint-space actions."""
    assert main(["train", str(arms["builtin"]), str(arms["twin"]), "--out", str(tmp_path / "run"), *TINY]) == 0


# ------------------------------------------------------------------------------------------ refusals
def synthetic(path: Path, joints: int, action: str = "joint_pos", extra_obs: bool = True, scale: float = 1.0) -> Path:
    """A 4-episode store of an arm with ``joints`` joints, actions ``joint_pos`` or ``ee7``, observations
    uniform in [-scale, scale]."""
    if action == "joint_pos":
        spec = ActionSpec("joint_pos", tuple(f"j{i}.target" for i in range(joints)) + ("gripper",),
                          ("rad",) * joints + ("1",), frame="joint", params={"arm_joints": [f"j{i}" for i in range(joints)]})
    else:
        spec = ActionSpec("ee7", ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"), ("m",) * 3 + ("rad",) * 3 + ("1",))
    features = {"obs.joint_pos": FeatureSpec((joints,), "float32"), "obs.ee_pos": FeatureSpec((3,), "float32")}
    if extra_obs:
        features["obs.object_pos"] = FeatureSpec((1, 3), "float32")
    meta = StoreMeta(fps=20.0, features=features, action=spec, robot={"name": f"arm{joints}", "config": "builtin"},
                     task={"name": "synthetic", "options": {}, "horizon": 20})
    rng = np.random.default_rng(joints)
    with EpisodeStore.create(path, meta) as store:
        for i in range(4):
            frames = {k: rng.uniform(-scale, scale, (20, *f.shape)).astype(np.float32) for k, f in features.items()}
            store.append_episode({**frames, "action": rng.uniform(-1, 1, (20, spec.dim)).astype(np.float32)},
                                 success=True, seed=i, source="synthetic")
    return path


def refusal(tmp_path: Path, a: Path, b: Path, obs_keys: tuple[str, ...] = ()) -> str:
    config = for_policy("bc", data=(str(a), str(b)), out=str(tmp_path / "run"), obs_keys=obs_keys, chunk=2)
    with open_stores(config.stores) as stores, pytest.raises(DemoError) as exc:
        prepare_union(config, stores)
    assert not (tmp_path / "run").exists()
    return str(exc.value)


def test_refuses_joint_actions_of_arms_with_different_joints(tmp_path: Path) -> None:
    a, b = synthetic(tmp_path / "seven.zarr", 7), synthetic(tmp_path / "six.zarr", 6)
    message = refusal(tmp_path, a, b)
    assert message.startswith(f"{b}: joint_pos actions of 6 joints")
    assert "joint-space actions of arms with different joints cannot share a policy" in message
    assert "demo convert STORE --to ee7" in message


def test_refuses_mixed_representations(tmp_path: Path) -> None:
    a, b = synthetic(tmp_path / "ee.zarr", 7, "ee7"), synthetic(tmp_path / "joint.zarr", 7)
    assert refusal(tmp_path, a, b).startswith(f"{b}: holds joint_pos actions (8 values), {a} ee7 (7)")


def test_refuses_observations_of_another_shape_or_missing(tmp_path: Path) -> None:
    a, b = synthetic(tmp_path / "seven.zarr", 7, "ee7"), synthetic(tmp_path / "six.zarr", 6, "ee7")
    message = refusal(tmp_path, a, b)  # the default observations include obs.joint_pos
    assert message.startswith(f"{b}: observation obs.joint_pos is (6,) here and (7,) in {a}")
    assert "--obs-keys obs.ee_pos," in message
    c = synthetic(tmp_path / "bare.zarr", 7, "ee7", extra_obs=False)
    message = refusal(tmp_path, a, c, ("obs.ee_pos", "obs.object_pos"))
    assert message.startswith(f"{c}: has no observation 'obs.object_pos'") and "--obs-keys" in message


def test_robot_agnostic_union_of_different_arms_prepares(tmp_path: Path) -> None:
    a, b = synthetic(tmp_path / "seven.zarr", 7, "ee7"), synthetic(tmp_path / "six.zarr", 6, "ee7", scale=3.0)
    config = for_policy("bc", data=(str(a), str(b)), out="unused", obs_keys=("obs.ee_pos", "obs.object_pos"), chunk=2)
    with open_stores(config.stores) as stores:
        data = prepare_union(config, stores)
        raw = [s.load(["obs.ee_pos"])[0]["obs.ee_pos"] for s in stores]
    assert data.obs.shape == (160, 6) and len(data.train_episodes) + len(data.val_episodes) == 8
    # The normaliser spans the union's training frames: the wider store sets it.
    train = np.concatenate([raw[0][[f for e in data.train_episodes[data.train_episodes < 4] for f in range(20 * e, 20 * e + 20)]],
                            raw[1][[f for e in data.train_episodes[data.train_episodes >= 4] - 4 for f in range(20 * e, 20 * e + 20)]]])
    np.testing.assert_allclose(data.obs_norm.low[:3], train.min(axis=0), rtol=1e-6)
    np.testing.assert_allclose(data.obs_norm.high[:3], train.max(axis=0), rtol=1e-6)
    assert data.obs_norm.high[0] > 1.5  # from the second store
    # Each store is split on its own: both contribute validation episodes.
    assert (data.val_episodes < 4).any() and (data.val_episodes >= 4).any()


def test_cli_union_refusal_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a, b = synthetic(tmp_path / "seven.zarr", 7), synthetic(tmp_path / "six.zarr", 6)
    assert main(["train", str(a), str(b), "--out", str(tmp_path / "run")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {b}: joint_pos actions of 6 joints")
    assert not (tmp_path / "run").exists()
    assert main(["train", str(a), str(b), "--algo", "dagger", "--out", str(tmp_path / "run")]) != 0
