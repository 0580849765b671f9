"""`--json -`: every command that has `--json` puts exactly one JSON document on stdout, and nothing
else (tables and progress bars go to stderr). The commands are enumerated from the typer app, so a
new command with `--json` fails :func:`test_every_json_command_is_covered` until it has a case here.

Each case runs on tiny inputs (two `reach` episodes, 20 training steps, benchmarks at their smallest
sizes); the whole module takes about a minute on one core.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from demo.cli.main import commands, main

STEPS = "20"


class Inputs:
    """Shared inputs, made once per module and on first use: a store, a trained run, a LeRobot export."""

    def __init__(self, root: Path):
        self.root = root

    @property
    def store(self) -> Path:
        path = self.root / "reach.zarr"
        if not path.exists():
            from demo.collect.scripted import CollectConfig, collect_scripted

            collect_scripted(CollectConfig(task="reach", episodes=2, seed=0), path, workers=0)
        return path

    @property
    def run(self) -> Path:
        path = self.root / "run"
        if not path.exists():
            assert main(["train", str(self.store), "--steps", STEPS, "--out", str(path)]) == 0
        return path

    @property
    def lerobot(self) -> Path:
        path = self.root / "exported"
        if not path.exists():
            from demo.interop.lerobot import export_lerobot

            export_lerobot(self.store, path)
        return path

    def new(self, name: str) -> str:
        """A path that does not exist yet, for a command's --out."""
        return str(self.root / "out" / name)


Case = Callable[[Inputs], tuple[list[str], set[str]]]  # -> (arguments before --json, keys the JSON must hold)

CASES: dict[str, Case] = {
    "collect": lambda i: (["--task", "reach", "--episodes", "2", "--workers", "0", "--out", i.new("c.zarr")],
                          {"out", "episodes", "successes", "success_rate", "frames"}),
    "info": lambda i: ([str(i.store), "--check"], {"episodes", "frames", "action", "features", "check"}),
    "curate": lambda i: ([str(i.store), "--out", i.new("curated.zarr")], {"summary", "episodes", "operators", "thresholds"}),
    "convert": lambda i: ([str(i.store), "--to", "ee7", "--out", i.new("ee7.zarr"), "--round-trip", "--check", "--episodes", "1"],
                          {"convert", "round_trip", "check"}),
    "export": lambda i: ([str(i.store), "--format", "robomimic", "--out", i.new("d.hdf5")], {"format", "episodes", "frames"}),
    "import": lambda i: ([str(i.lerobot), "--out", i.new("imported.zarr")], {"format", "episodes", "frames"}),
    "train": lambda i: ([str(i.store), "--steps", STEPS, "--out", i.new("run")], {"out", "step", "train_loss"}),
    "eval": lambda i: ([str(i.run), "--episodes", "2"], {"success_rate", "ci95", "episodes", "failures"}),
    "quickstart": lambda i: (["--task", "reach", "--episodes", "2", "--poor", "1", "--steps", STEPS, "--eval-episodes", "2",
                              "--workers", "1", "--out", i.new("quickstart")],
                             {"collect", "curate", "convert", "train", "eval"}),
    "robot init": lambda i: ([str(Path(__file__).resolve().parents[2] / "sim" / "assets" / "panda.xml"), "--out", i.new("arm.toml")],
                             {"out", "joints", "actuators", "config", "notes", "reach"}),
    "robot check": lambda i: ([str(Path(__file__).resolve().parents[2] / "sim" / "assets" / "panda.toml"), "--episodes", "1", "--targets", "1"], {"dof", "joints", "ik", "experts", "ok"}),
    "bench load": lambda i: (["--frames", "20000", "--seconds", "0.1"], {"samples_per_s", "reference_samples_per_s"}),
    "bench collect": lambda i: (["--task", "reach", "--episodes", "2", "--seconds", "0.1", "--rounds", "1"],
                                {"one_worker", "two_workers", "ratio_to_physics"}),
    "bench render": lambda i: (["--task", "reach", "--episodes", "2", "--seconds", "0.05", "--rounds", "1",
                                "--camera", "front@16x16", "--workers", "0"], {"figure", "reference", "ratio", "cpu_ratio"}),
    "bench convert": lambda i: (["--frames", "2000", "--placo-frames", "200"], {"results", "target_met"}),
    "bench curate": lambda i: (["--frames", "5000"], {"frames_per_s", "reference_frames_per_s"}),
    "bench retarget": lambda i: (["--task", "reach", "--seconds", "0.1", "--ik", "mink"], {"backends"}),
    "bench train": lambda i: (["--frames", "5000", "--seconds", "0.1", "--hidden", "32,32"],
                              {"samples_per_s", "reference_samples_per_s"}),
    "bench infer": lambda i: (["--seconds", "0.3"], {"ms_per_chunk", "reference_ms_per_chunk"}),
    "bench samplers": lambda i: (["--seconds", "0.2", "--steps", "1,2"], {"ms_per_chunk", "reference_ms_per_chunk",
                                                                          "ratio_to_reference"}),
    "bench serve": lambda i: (["--policies", "bc", "--seconds", "0.3", "--clients", "2"],
                              {"results", "seconds_per_policy", "clients", "machine"}),
    "bench faults": lambda i: (["--episodes", "50", "--kills", "1", "--append-kills", "0", "--races", "0", "--creates", "0",
                                "--max-kill-s", "1"], {"scenarios", "finished_lost", "ok"}),
}
SKIPS = {
    "bench multimodal": "needs a diffusion and a BC run trained on avoid; "
                        "tests/bench/test_diffusion_bench.py runs it end to end with --json - and parses stdout",
    "bench compounding": "collects, trains and evaluates BC, chunked BC, DART and the DAgger family per horizon (~1 min in "
                         "miniature); "
                         "tests/experiments/test_compounding.py runs it end to end with --json - and parses stdout",
    "bench crossrobot": "collects on two arms, trains five policies and evaluates eight pairs (~14 s in miniature); "
                        "tests/experiments/test_crossrobot.py runs it end to end with --json - and parses stdout",
    "bench policies": "collects, trains and evaluates one policy per class (and a distillation); "
                      "tests/experiments/test_policies.py runs it in miniature with --json FILE and reads it",
    "bench suite": "needs the metaworld package (optional); tests/experiments/test_suite.py runs it in miniature "
                   "with --json FILE where it is installed",
    "bench env": "needs a run trained on a Gymnasium environment; tests/collect/test_foreign_env.py runs it with --json FILE "
                 "on one",
    "irl train": "trains a PPO inner loop per algorithm; "
                 "tests/rl/test_irl.py runs each algorithm in miniature with --json FILE",
    "bench resume": "kills and resumes real demo train processes (~40 s in miniature); "
                    "tests/training/test_trainer.py runs it with --json FILE and reads it",
    "bench realtime": "needs a trained run and runs real-time episodes; tests/deploy/test_realtime.py runs it with "
                      "--json FILE and reads it",
    "bench delay": "needs a trained run; tests/deploy/test_realtime.py runs it with --json FILE and reads it",
    "bench peer-gail": "needs the imitation library, installed in its own venv only (README); "
                       "tests/experiments/test_peer_gail.py runs it "
                       "in miniature there with --json FILE",
}


def json_commands() -> set[str]:
    """Every visible command (``"bench load"`` for subcommands) that has a ``--json`` option."""
    return {name for name, command in commands().items() if any("--json" in getattr(p, "opts", ()) for p in command.params)}


def test_every_json_command_is_covered() -> None:
    commands = json_commands()
    assert {"collect", "curate", "eval", "bench load"} <= commands  # the walk finds commands and subcommands
    assert commands - set(CASES) - set(SKIPS) == set(), "add a case (or a skip with its reason) for these commands"
    assert set(CASES) | set(SKIPS) <= commands, "a case for a command without --json (renamed?)"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> Inputs:
    return Inputs(tmp_path_factory.mktemp("json"))


# The benchmarks that take seconds each, and quickstart (every stage), run in the full suite only.
SLOW = {"bench infer", "bench faults", "bench collect", "bench render", "bench curate", "quickstart"}


@pytest.mark.parametrize("command", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW else c
                                     for c in [*CASES, *SKIPS]])
def test_json_to_stdout_is_the_only_stdout(command: str, inputs: Inputs, capfd: pytest.CaptureFixture,
                                           torch_one_thread: None) -> None:
    if command in SKIPS:
        pytest.skip(SKIPS[command])
    args, keys = CASES[command](inputs)
    capfd.readouterr()  # whatever making the inputs printed
    rc = main([*command.split(), *args, "--json", "-"])
    out, err = capfd.readouterr()
    assert rc == 0, err
    data = json.loads(out)  # fails on anything but one JSON document (a table, a bar, a stray line)
    assert isinstance(data, dict) and keys <= set(data), sorted(data)
    assert out.endswith("}\n")
