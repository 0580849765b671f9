"""Domain randomisation and the shift suite (demo.sim.randomize, demo.evaluation.shifts): draws from the
episode's seed (same seed, same scene; the start state unchanged), shifts growing with the level, the
nominal scene restored, the experts still succeeding at the heaviest level, collection recording each
episode's draws, and `demo eval --shift` on the same start states at every level."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.sim import make_env
from demo.sim.randomize import KINDS, Randomization, gaussian_blur
from demo.sim.rollout import run_expert
from demo.store import EpisodeStore

VISUAL = ("lighting", "camera", "texture", "noise", "blur")


@pytest.fixture(scope="module")
def env():
    e = make_env("pick", cameras=["front@32x32"])
    yield e
    e.close()


def test_draws_come_from_the_seed_and_leave_the_start_state(env) -> None:
    nominal = env.reset(11)
    for kind in KINDS:
        env.set_randomization(Randomization({kind: 2}))
        first, again = env.reset(11), None
        drawn = env.randomized
        env.reset(12)
        assert env.randomized != drawn or kind == "latency"  # another seed, other draws (latency is fixed per level)
        again = env.reset(11)
        assert env.randomized == drawn
        for key in first:
            np.testing.assert_array_equal(first[key], again[key], err_msg=f"{kind}: {key}")  # same seed, same scene
        for key in ("obs.joint_pos", "obs.object_pos", "obs.object_quat"):
            np.testing.assert_array_equal(first[key], nominal[key], err_msg=f"{kind}: {key}")  # the same start
        changed = not np.array_equal(first["obs.image_front"], nominal["obs.image_front"])
        assert changed == (kind in VISUAL), kind
    env.set_randomization(None)
    np.testing.assert_array_equal(env.reset(11)["obs.image_front"], nominal["obs.image_front"])  # restored


def test_pixel_noise_and_blur_are_functions_of_seed_and_time(env) -> None:
    """Noise: fresh at each step, the same for the same state at the same time (a replay sees the same pixels);
    its spread the episode's draw. Blur: a flat image stays flat, an edge is spread over a few pixels."""
    nominal = env.reset(21)["obs.image_front"].astype(float)
    env.set_randomization(Randomization({"noise": 3}))
    first = env.reset(21)["obs.image_front"]
    sigma = env.randomized["noise"]["sigma"]
    assert 0 < sigma <= 16 and abs(np.std(first - nominal) - sigma) < 0.35 * sigma + 1  # clipped at 0 and 255
    state = env.get_state()
    step = env.step(np.r_[env.observe()["obs.joint_pos"], 0.0])[0]["obs.image_front"]
    assert not np.array_equal(step, first)  # another time, other noise
    env.set_state(state)
    np.testing.assert_array_equal(env.observe()["obs.image_front"], first)
    env.set_randomization(None)
    flat = np.full((8, 8, 3), 100.0)
    np.testing.assert_allclose(gaussian_blur(flat, 1.0), flat)
    edge = np.zeros((1, 9, 1))
    edge[:, 5:] = 255.0
    blurred = gaussian_blur(edge, 1.0)[0, :, 0]
    assert 0 < blurred[4] < 127.5 < blurred[5] < 255 and blurred[0] == 0 and np.all(np.diff(blurred) >= 0)


def test_a_higher_level_shifts_the_same_way_further(env) -> None:
    deviation = []
    for level in (1, 2, 3):
        env.set_randomization(Randomization({"friction": level, "mass": level}))
        env.reset(5)
        deviation.append((env.randomized["friction"]["scale"] - 1, np.log2(env.randomized["mass"]["scale"])))
    env.set_randomization(None)
    d = np.array(deviation)
    assert (np.sign(d) == np.sign(d[0])).all() and (np.abs(d[1:]) > np.abs(d[:-1])).all()


def test_the_expert_succeeds_at_the_heaviest_level_of_each_physical_kind(env) -> None:
    for kind in ("friction", "mass", "latency"):
        env.set_randomization(Randomization({kind: 3}))
        assert sum(run_expert(env, 100 + s).success for s in range(4)) == 4, kind
    env.set_randomization(None)


def test_latency_holds_a_command_back(env) -> None:
    """A command acts 60 ms late: the first step still holds the reset configuration."""
    env.set_randomization(None)
    start = env.reset(3)["obs.joint_pos"].copy()
    target = np.r_[start + 0.2, 0.0]
    moved = env.step(target)[0]["obs.joint_pos"] - start
    env.set_randomization(Randomization({"latency": 3}))
    env.reset(3)
    held = env.step(target)[0]["obs.joint_pos"] - start
    later = env.step(target)[0]["obs.joint_pos"] - start
    env.set_randomization(None)
    assert np.abs(held).max() < 0.1 * np.abs(moved).max() and np.abs(later).max() > 0.2 * np.abs(moved).max()


def test_bad_randomizations_are_one_line_errors(tmp_path: Path) -> None:
    assert Randomization.parse("medium").levels == {kind: 2 for kind in KINDS}
    assert Randomization.parse("friction=1,camera=3").levels == {"friction": 1, "camera": 3}
    (tmp_path / "r.toml").write_text("mass = 2\nlighting = 1\n")
    assert Randomization.parse(str(tmp_path / "r.toml")).levels == {"mass": 2, "lighting": 1}
    (tmp_path / "bad.toml").write_text("mass = [\n")
    for text, needle in [("wind=1", "unknown kind 'wind'"), ("friction=7", "friction level must be an integer 0..3"),
                         ("strong", "is not a preset"), (str(tmp_path / "bad.toml"), "not a randomisation TOML")]:
        with pytest.raises(DemoError, match=needle):
            Randomization.parse(text)


def test_collection_records_each_episodes_draws_and_they_replay(tmp_path: Path, one_line_error) -> None:
    out = tmp_path / "r.zarr"
    assert main(["collect", "--task", "pick", "--episodes", "3", "--seed", "2", "--camera", "front@32x32",
                 "--randomize", "texture=2,friction=1", "--workers", "0", "--out", str(out)]) == 0
    with EpisodeStore.open(out) as store:
        draws = [json.loads(d) for d in store.column("randomization")]
        assert {tuple(sorted(d)) for d in draws} == {("friction", "texture")}
        seed = int(store.column("seed")[1])
        frame0 = store.read_episode(1, ["obs.image_front"])["obs.image_front"][0]
    env = make_env("pick", cameras=["front@32x32"])
    env.set_randomization(Randomization({"texture": 2, "friction": 1}))
    np.testing.assert_array_equal(env.reset(seed)["obs.image_front"], frame0)  # the episode replays from its seed
    assert env.randomized == draws[1]
    env.close()
    one_line_error(["collect", "--task", "pick", "--episodes", "1", "--randomize", "wind=2", "--out",
                    str(tmp_path / "x.zarr")], "unknown kind 'wind'")
    assert not (tmp_path / "x.zarr").exists()


def test_the_shift_suite(tmp_path: Path, one_line_error) -> None:
    data, run = tmp_path / "pick.zarr", tmp_path / "run"
    assert main(["collect", "--task", "pick", "--episodes", "12", "--seed", "0", "--workers", "0", "--out", str(data)]) == 0
    assert main(["train", str(data), "--steps", "300", "--out", str(run)]) == 0
    out, png = tmp_path / "shift.json", tmp_path / "shift.png"
    assert main(["eval", str(run), "--shift", "friction", "--shift", "latency", "--level", "0..2", "--episodes", "4",
                 "--json", str(out), "--plot", str(png)]) == 0
    result = json.loads(out.read_text())
    assert list(result["shifts"]) == ["friction", "latency"] and result["levels"] == [0, 1, 2]
    assert result["shifts"]["friction"]["0"] == result["shifts"]["latency"]["0"]  # one nominal evaluation, shared
    assert png.stat().st_size > 0
    one_line_error(["eval", str(run), "--shift", "wind"], "unknown shift 'wind'")
    one_line_error(["eval", str(run), "--shift", "mass", "--level", "2..5"], "levels run from 0 to 3")
    one_line_error(["eval", str(run), "--plot", str(png)], "give --shift")
