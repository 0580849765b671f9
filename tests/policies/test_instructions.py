"""Instruction-conditioned policies (demo.policies.instruction): the words decide the goal.

A point between two coloured targets whose positions it observes; the episode's instruction ("go to
the red dot", or blue) says which one, and nothing else does. A policy trained on the instructions
reaches the named target; the same policy trained with the instructions blanked can only guess (about
half). Instructions travel from the environment through the store into the run, and an instruction
given at evaluation overrides the environment's; bad input fails in one line.
"""

from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path

import pytest

from demo.cli.main import main
from demo.interop.lerobot.layout import EXTRA_KEY
from demo.policies.checkpoint import load_bundle
from demo.store import EpisodeStore

TWO_DOTS = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np

    COLOURS = ("red", "blue")


    class TwoDots(gym.Env):
        """A point and two targets, red and blue; the instruction names the one to reach (within 10 cm)."""

        metadata = {"render_modes": [], "render_fps": 10}

        def __init__(self, target=None):  # "red" or "blue": every episode's; None: drawn per episode
            self.fixed = None if target is None else COLOURS.index(target)
            self.observation_space = gym.spaces.Box(-1.0, 1.0, (6,), np.float32)  # position, red, blue
            self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
            self.instruction = ""

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.pos = self.np_random.uniform(-0.2, 0.2, 2)
            angle = self.np_random.uniform(0, 2 * np.pi)
            offset = 0.6 * np.array([np.cos(angle), np.sin(angle)])
            self.dots = np.stack([offset, -offset])  # on opposite sides: a policy that guesses goes one way
            self.target = int(self.np_random.integers(2)) if self.fixed is None else self.fixed
            self.instruction = f"go to the {COLOURS[self.target]} dot"
            return self._obs(), {}

        def step(self, action):
            self.pos = np.clip(self.pos + 0.06 * np.clip(action, -1, 1), -1, 1)
            success = bool(np.linalg.norm(self.pos - self.dots[self.target]) < 0.1)
            return self._obs(), float(success), success, False, {"is_success": success}

        def _obs(self):
            return np.r_[self.pos, self.dots.ravel()].astype(np.float32)


    def expert(obs, env):
        goal = env.unwrapped.dots[env.unwrapped.target]
        return np.clip((goal - obs[:2]) / 0.06, -1.0, 1.0)


    gym.register("TwoDots-v0", entry_point=TwoDots, max_episode_steps=50)
''')


@pytest.fixture(scope="module")
def dots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The environment as a user's module, and 200 demonstrations."""
    folder = tmp_path_factory.mktemp("dots")
    (folder / "two_dots.py").write_text(TWO_DOTS)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(folder))
        mp.setenv("PYTHONPATH", str(folder))
        assert main(["collect", "--env", "two_dots:TwoDots-v0", "--expert", "two_dots:expert", "--episodes", "200",
                     "--seed", "0", "--workers", "0", "--out", str(folder / "dots.zarr")]) == 0
        yield folder


def train(dots: Path, out: Path, *extra: str) -> int:
    return main(["train", str(dots / "dots.zarr"), "--out", str(out), "--steps", "1500", "--chunk", "1",
                 "--no-ensemble", "--seed", "0", *extra])


def evaluate(run: Path, json_path: Path, *extra: str) -> dict:
    assert main(["eval", str(run), "--episodes", "40", "--seed", "1", "--json", str(json_path), *extra]) == 0
    return json.loads(json_path.read_text())


def test_the_words_decide_the_goal(dots: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(dots))
    with EpisodeStore.open(dots / "dots.zarr") as store:
        told = store.column("instruction").tolist()
    assert set(told) == {"go to the red dot", "go to the blue dot"} and store.column("success").all()

    assert train(dots, tmp_path / "words") == 0  # auto: the episodes hold two instructions
    bundle = load_bundle(tmp_path / "words")
    assert bundle.tokenizer is not None and bundle.policy.spec.vocab == bundle.tokenizer.vocab_size
    assert bundle.tokenizer.unknown_words("go to the green dot") == ["green"]
    followed = evaluate(tmp_path / "words", tmp_path / "w.json", "--record", str(tmp_path / "rollouts.zarr"))
    assert followed["success_rate"] >= 0.9, followed["success_rate"]
    # each episode's instruction (the environment's own here) is in the JSON and the recorded store alike
    each = [episode["instruction"] for episode in followed["episodes_detail"]]
    assert set(each) == set(told)
    with EpisodeStore.open(tmp_path / "rollouts.zarr") as rollouts:
        assert rollouts.column("instruction").tolist() == each
    per_task = json.loads((tmp_path / "words" / "metrics.json").read_text())["val_loss_per_instruction"]
    assert set(per_task) == set(told) and all(0 < v < 1 for v in per_task.values())  # each task validated alone

    assert train(dots, tmp_path / "blank", "--no-instructions") == 0
    assert load_bundle(tmp_path / "blank").tokenizer is None
    assert "val_loss_per_instruction" not in json.loads((tmp_path / "blank" / "metrics.json").read_text())
    guessed = evaluate(tmp_path / "blank", tmp_path / "b.json")
    assert guessed["success_rate"] <= 0.7, guessed["success_rate"]  # a guess between two: about half

    # Told the other colour than the environment wants, the policy goes there: success falls.
    red = evaluate(tmp_path / "words", tmp_path / "r.json", "--instruction", "go to the RED dot")
    assert red["instruction"] == "go to the RED dot" and red["unknown_words"] == []
    assert {episode["instruction"] for episode in red["episodes_detail"]} == {"go to the RED dot"}
    assert red["success_rate"] < followed["success_rate"] - 0.25


def test_bad_instructions_fail_in_one_line(dots: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           one_line_error) -> None:
    monkeypatch.syspath_prepend(str(dots))
    one_line_error(["collect", "--env", "two_dots:TwoDots-v0", "--expert", "two_dots:expert", "--episodes", "2",
                    "--instruction", "   ", "--out", str(tmp_path / "x.zarr")], "--instruction", "empty")
    one_line_error(["collect", "--env", "two_dots:TwoDots-v0", "--expert", "two_dots:expert", "--episodes", "2",
                    "--instruction", "go " * 300, "--out", str(tmp_path / "x.zarr")], "--instruction", "at most 500")
    assert not (tmp_path / "x.zarr").exists()
    assert train(dots, tmp_path / "blank", "--no-instructions", "--steps", "50") == 0
    one_line_error(["eval", str(tmp_path / "blank"), "--episodes", "1", "--instruction", "go to the red dot"],
                   "trained without instructions")
    one_line_error(["train", str(dots / "dots.zarr"), "--out", str(tmp_path / "t"), "--steps", "10",
                    "--text-opt", "dim=30", "--text-opt", "heads=4"], "--text-opt", "multiple of heads")
    # A store some of whose episodes have no instruction cannot train a policy that follows them.
    assert main(["collect", "--env", "two_dots:TwoDots-v0", "--expert", "two_dots:expert", "--episodes", "4",
                 "--workers", "0", "--out", str(tmp_path / "mixed.zarr")]) == 0
    with EpisodeStore.open(tmp_path / "mixed.zarr", mode="a") as store:
        store.set_column("instruction", ["go to the red dot", "", "go to the blue dot", "go"])
    one_line_error(["train", str(tmp_path / "mixed.zarr"), "--out", str(tmp_path / "m"), "--steps", "10",
                    "--instructions", "--val-fraction", "0"], "mixed.zarr", "episode 1 has no instruction")


def test_instructions_are_lerobots_tasks_both_ways(dots: Path, tmp_path: Path) -> None:
    """Exported, each episode's instruction is its LeRobot task (meta/tasks.parquet, per-frame task_index);
    imported back, the instruction column is the same; a LeRobot dataset demo did not write gives its tasks
    as the instructions."""
    import pyarrow.parquet as pq

    assert main(["export", str(dots / "dots.zarr"), "--format", "lerobot", "--out", str(tmp_path / "lr")]) == 0
    tasks = pq.read_table(tmp_path / "lr" / "meta" / "tasks.parquet").column("task").to_pylist()
    assert sorted(tasks) == ["go to the blue dot", "go to the red dot"]
    assert main(["import", str(tmp_path / "lr"), "--out", str(tmp_path / "back.zarr")]) == 0
    with EpisodeStore.open(dots / "dots.zarr") as a, EpisodeStore.open(tmp_path / "back.zarr") as b:
        assert b.column("instruction").tolist() == a.column("instruction").tolist()
        assert b.column("task").tolist() == a.column("task").tolist()
    # Another writer's dataset: no demo columns, the tasks alone say what each episode was told.
    info = json.loads((tmp_path / "lr" / "meta" / "info.json").read_text())
    info.pop(EXTRA_KEY)
    (tmp_path / "lr" / "meta" / "info.json").write_text(json.dumps(info))
    assert main(["import", str(tmp_path / "lr"), "--out", str(tmp_path / "foreign.zarr")]) == 0
    with EpisodeStore.open(dots / "dots.zarr") as a, EpisodeStore.open(tmp_path / "foreign.zarr") as b:
        assert b.column("instruction").tolist() == a.column("instruction").tolist()


# A Python with lerobot 0.4.4 (tests/interop/test_lerobot.py says how to make one); the check skips without it.
LEROBOT_PYTHON = os.environ.get("DEMO_LEROBOT_PYTHON")
LEROBOT_TASKS = """
import json, sys
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset(repo_id="local/x", root=sys.argv[1])
print(json.dumps([[int(ds[i]["episode_index"]), ds[i]["task"]] for i in range(len(ds))]))
"""


@pytest.mark.skipif(not LEROBOT_PYTHON, reason="LeRobot is not installed: set DEMO_LEROBOT_PYTHON to a Python that "
                    "has lerobot to read the export with LeRobotDataset")
def test_lerobot_reads_each_frames_instruction_as_its_task(dots: Path, tmp_path: Path) -> None:
    import subprocess

    assert main(["export", str(dots / "dots.zarr"), "--format", "lerobot", "--out", str(tmp_path / "lr")]) == 0
    done = subprocess.run([LEROBOT_PYTHON, "-c", LEROBOT_TASKS, str(tmp_path / "lr")], check=True, capture_output=True,
                          text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"}, timeout=600)
    frames = json.loads(done.stdout.strip().splitlines()[-1])
    with EpisodeStore.open(dots / "dots.zarr") as store:
        told = store.column("instruction").tolist()
        lengths = store.column("length").tolist()
    assert len(frames) == sum(lengths)
    assert all(task == told[episode] for episode, task in frames)
    assert {task for _, task in frames} == {"go to the blue dot", "go to the red dot"}


def test_stores_of_different_tasks_mix_into_one_policy_with_weights(dots: Path, tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch, one_line_error) -> None:
    """Red-only and blue-only stores (different tasks: the environment's options differ) train one policy because
    their episodes carry instructions; --mix's weights decide what it learns: blue at weight 0 is not learnt."""
    monkeypatch.syspath_prepend(str(dots))
    for colour in ("red", "blue"):
        assert main(["collect", "--env", "two_dots:TwoDots-v0", "--env-opt", f"target={colour}", "--expert",
                     "two_dots:expert", "--episodes", "100", "--seed", "5" if colour == "red" else "6", "--workers", "0",
                     "--out", str(tmp_path / f"{colour}.zarr")]) == 0
    red, blue = str(tmp_path / "red.zarr"), str(tmp_path / "blue.zarr")
    common = ["--steps", "1500", "--chunk", "1", "--no-ensemble", "--seed", "0"]
    assert main(["train", "--mix", f"{red}=0.5", "--mix", f"{blue}=0.5", "--out", str(tmp_path / "even"), *common]) == 0
    assert main(["train", "--mix", f"{red}=1", "--mix", f"{blue}=0", "--out", str(tmp_path / "red_only"), *common]) == 0
    run = json.loads((tmp_path / "even" / "run.json").read_text())
    assert [s["weight"] for s in run["data"]["stores"]] == [0.5, 0.5] and run["train"]["mix"] == [0.5, 0.5]
    on_blue = ["--env", "two_dots:TwoDots-v0", "--env-opt", "target=blue"]
    even = evaluate(tmp_path / "even", tmp_path / "e.json", *on_blue)
    red_only = evaluate(tmp_path / "red_only", tmp_path / "r.json", *on_blue)
    assert even["success_rate"] >= 0.9 and red_only["success_rate"] <= 0.2, (even["success_rate"], red_only["success_rate"])
    one_line_error(["train", "--mix", f"{red}=0.7", "--mix", f"{blue}=0.7", "--out", str(tmp_path / "x")], "--mix",
                   "sum to 1")
    one_line_error(["train", red, "--mix", f"{blue}=1", "--out", str(tmp_path / "x")], "--mix", "either")
    one_line_error(["train", "--mix", f"{red}", "--out", str(tmp_path / "x")], "--mix", "STORE=WEIGHT")
    one_line_error(["train", red, blue, "--no-instructions", "--out", str(tmp_path / "x")], "blue.zarr",
                   "unless every episode carries an instruction")


def test_bc_takes_the_instruction_by_film_and_other_policies_appended() -> None:
    """BC's MLP on state: FiLM in its hidden layers (the identity at initialisation, so the words' effect is
    learnt); film=false and every other policy: the vector appended to the observation."""
    import torch

    from demo.policies.instruction import CONDITION, INSTRUCTION
    from demo.policies.policy import PolicySpec, build_policy

    spec = PolicySpec(5, 2, 1, 4, vocab=12, max_tokens=3)
    torch.manual_seed(0)
    film = build_policy("bc", spec, {"hidden": (16, 16)})
    assert film.film and film.inner.spec.obs_dim == 5 and film.inner.spec.cond_dim == 64
    appended = build_policy("bc", spec, {"hidden": (16, 16)}, text={"film": "false"})
    assert not appended.film and appended.inner.spec.obs_dim == 5 + 64
    assert not build_policy("flow", spec, {"width": 16, "depth": 1}).film
    obs = {"state": torch.randn(3, 1, 5), INSTRUCTION: torch.tensor([[2, 3, 0], [4, 0, 0], [2, 3, 0]])}
    conditioned = film.condition(obs)
    assert torch.equal(conditioned[CONDITION][0], conditioned[CONDITION][2])  # one instruction, one vector
    plain = {"state": obs["state"]}
    with torch.no_grad():  # zero-initialised FiLM: the MLP's output does not depend on the words yet
        a = film.inner(conditioned)
        b = film.inner.head.outputs(film.inner.net(plain["state"].reshape(3, -1)))
    assert torch.allclose(a, b)


def test_a_tampered_instruction_record_is_refused_in_one_line(dots: Path, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch, one_line_error) -> None:
    """run.json is untrusted: a tokenizer that does not parse, or whose vocabulary disagrees with the policy's
    spec, is one line naming the file; nothing is unpickled or executed."""
    monkeypatch.syspath_prepend(str(dots))
    assert train(dots, tmp_path / "run", "--steps", "20") == 0
    path = tmp_path / "run" / "run.json"
    run = json.loads(path.read_text())
    broken = json.loads(json.dumps(run))
    broken["policy"]["instruction"]["tokenizer"] = {"model": {"type": "Nothing"}}
    path.write_text(json.dumps(broken))
    one_line_error(["eval", str(tmp_path / "run"), "--episodes", "1"], "run.json", "malformed policy record",
                   "tokenizer does not read")
    grown = json.loads(json.dumps(run))
    grown["policy"]["spec"]["vocab"] += 1
    path.write_text(json.dumps(grown))
    one_line_error(["eval", str(tmp_path / "run"), "--episodes", "1"], "run.json", "does not match the policy's spec")


def test_a_pretrained_text_encoder_starts_another_run(dots: Path, tmp_path: Path, one_line_error) -> None:
    """--text-opt init=RUN: the tokenizer and text encoder of an earlier instruction-conditioned run start this
    one (its shape too), frozen with freeze=true; a run without one, or another shape asked for, is refused."""
    import torch

    common = ["--steps", "40", "--chunk", "1", "--no-ensemble", "--seed", "0"]
    first, frozen, tuned = tmp_path / "first", tmp_path / "frozen", tmp_path / "tuned"
    assert main(["train", str(dots / "dots.zarr"), "--out", str(first), "--text-opt", "dim=32", "--text-opt", "heads=2", *common]) == 0
    assert main(["train", str(dots / "dots.zarr"), "--out", str(frozen), "--text-opt", f"init={first}", "--text-opt", "freeze=true",
                 *common, "--seed", "1"]) == 0
    assert main(["train", str(dots / "dots.zarr"), "--out", str(tuned), "--text-opt", f"init={first}", *common]) == 0
    a, b, c = load_bundle(first), load_bundle(frozen), load_bundle(tuned)
    assert b.tokenizer.to_json() == a.tokenizer.to_json() and b.policy.text_config.dim == 32
    weights = a.policy.text.state_dict()
    assert all(torch.equal(v, b.policy.text.state_dict()[k]) for k, v in weights.items())  # frozen: unchanged
    assert not all(torch.equal(v, c.policy.text.state_dict()[k]) for k, v in weights.items())  # fine-tuned: moved
    assert json.loads((frozen / "run.json").read_text())["policy"]["text"]["init"] == str(first)
    one_line_error(["train", str(dots / "dots.zarr"), "--out", str(tmp_path / "bad"), "--text-opt",
                    f"init={first}", "--text-opt", "dim=64", *common], "--text-opt", "dim=64")
    one_line_error(["train", str(dots / "dots.zarr"), "--out", str(tmp_path / "off"), "--text-opt", f"init={first}",
                    "--no-instructions", *common], "--text-opt", "--no-instructions")
    plain = tmp_path / "plain"
    assert main(["train", str(dots / "dots.zarr"), "--out", str(plain), "--no-instructions", *common]) == 0
    one_line_error(["train", str(dots / "dots.zarr"), "--out", str(tmp_path / "bad2"), "--text-opt", f"init={plain}",
                    *common], str(plain), "not an instruction-conditioned run")


@pytest.mark.slow
def test_a_transformer_reads_the_words_as_tokens(dots: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--algo transformer: the instruction's per-word tokens beside the observation's (and each camera's) tokens;
    it follows the words as the FiLM MLP does, and a run evaluates like any other."""
    import torch

    from demo.policies.instruction import INSTRUCTION, TEXT_TOKENS
    from demo.policies.policy import PolicySpec, build_policy

    spec = PolicySpec(5, 2, 2, 4, images=(("obs.image_front", 32, 32), ("obs.image_wrist", 32, 32)), vocab=12,
                      max_tokens=3)
    torch.manual_seed(0)
    policy = build_policy("transformer", spec, {"d_model": 32, "layers": 1, "feedforward": 64},
                          encoder={"features": 8})
    inner = policy.inner.head  # the instruction wrapper, the camera encoders, the transformer
    assert policy.tokens and inner.spec.token_dims == (5, 8, 8) and inner.spec.text_dim == 64
    assert "token_dims" not in inner.spec.to_json() and "text_dim" not in inner.spec.to_json()
    images = {k: torch.randint(0, 255, (2, 2, 32, 32, 3), dtype=torch.uint8) for k, _, _ in spec.images}
    state = torch.randn(1, 2, 5).expand(2, -1, -1)
    obs = {"state": state, **{k: v[:1].expand(2, -1, -1, -1, -1) for k, v in images.items()},
           INSTRUCTION: torch.tensor([[2, 3, 0], [4, 5, 6]])}
    policy.eval()
    chunks = policy.predict(obs)
    assert chunks.shape == (2, 4, 2) and not torch.allclose(chunks[0], chunks[1])  # the words alone differ
    assert TEXT_TOKENS in policy.condition(obs)

    monkeypatch.syspath_prepend(str(dots))
    out = tmp_path / "transformer"
    assert train(dots, out, "--algo", "transformer", "--policy-opt", "d_model=32", "--policy-opt", "layers=2",
                 "--policy-opt", "feedforward=128", "--policy-opt", "dropout=0", "--batch-size", "64") == 0
    assert load_bundle(out).policy.tokens
    followed = evaluate(out, tmp_path / "t.json")
    assert followed["success_rate"] >= 0.9, followed["success_rate"]
