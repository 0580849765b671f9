"""`demo bench infer` (latency per chunk against DDPM-100) and the avoid path classification."""

from __future__ import annotations

import json

import numpy as np
import pytest

from demo.bench.infer import run as bench_infer
from demo.experiments.multimodal import classify


pytestmark = [pytest.mark.usefixtures("torch_one_thread"), pytest.mark.slow]  # trains diffusion runs: ~23 s


def test_bench_infer_measures_figure_and_reference_in_one_run() -> None:
    r = bench_infer(denoiser="unet", channels=(16, 32), steps=4, obs_dim=6, action_dim=3, horizon=8, seconds=0.05)
    assert r["inference_steps"] == 4 and r["channels"] == [16, 32] and r["batch"] == 1
    for key in ("ms_per_chunk", "reference_ms_per_chunk", "ddim_eager_ms_per_chunk", "ddpm_fast_path_ms_per_chunk"):
        assert r[key] > 0
    # 100 full network calls against 4 cached-conditioning ones: far slower, even on a busy machine
    assert r["speedup_vs_reference"] > 4
    assert r["speedup_from_fewer_steps"] > 4
    json.dumps(r)


def test_bench_infer_cli_writes_json(tmp_path) -> None:
    from demo.cli.main import main

    out = tmp_path / "infer.json"
    rc = main(["bench", "infer", "--denoiser", "mlp", "--inference-steps", "2", "--seconds", "0.02", "--json", str(out)])
    assert rc == 0
    r = json.loads(out.read_text())
    assert r["inference_steps"] == 2 and r["denoiser"] == "mlp" and r["reference_ms_per_chunk"] > r["ms_per_chunk"]
    assert main(["bench", "infer", "--denoiser", "unet", "--channels", "16,x", "--json", str(out)]) == 1
    assert main(["bench", "infer", "--denoiser", "transformer", "--json", str(out)]) == 1


def test_classify_sides() -> None:
    obstacle = np.array([0.47, 0.01, 0.12])
    x = np.linspace(0.3, 0.65, 30)
    left = np.stack([x, 0.01 + 0.15 * np.sin(np.pi * (x - 0.3) / 0.35), np.full_like(x, 0.1)], axis=1)
    right = left * np.array([1, -1, 1]) + np.array([0, 0.02, 0])
    assert classify(left, obstacle) == "left"
    assert classify(right, obstacle) == "right"
    assert classify(left[:5], obstacle) == "none"  # never got past the obstacle


def test_bench_multimodal_end_to_end(tmp_path, capfd) -> None:
    """Collect a few avoid demos, train diffusion and BC briefly, compare their paths: JSON + PNG (the CLI)."""
    from demo.cli.main import main
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.imitation.bc import train
    from demo.training.config import TrainConfig

    data = tmp_path / "avoid.zarr"
    collect_scripted(CollectConfig(task="avoid", episodes=4, seed=0), data)
    common = dict(data=str(data), steps=20, batch_size=16, warmup_steps=2, val_fraction=0.0, log_every=10)
    train(TrainConfig(algo="diffusion", out=str(tmp_path / "diffusion"), policy={"denoiser": "mlp", "width": 32, "depth": 1,
                                                                   "inference_steps": 2}, **common))
    train(TrainConfig(out=str(tmp_path / "bc"), algo="bc", policy={"hidden": (16,)}, **common))
    png = tmp_path / "modes.png"
    capfd.readouterr()
    rc = main(["bench", "multimodal", "--diffusion", str(tmp_path / "diffusion"), "--reference", str(tmp_path / "bc"),
               "--starts", "2", "--samples", "2", "--png", str(png), "--json", "-"])
    assert rc == 0 and png.stat().st_size > 10_000
    r = json.loads(capfd.readouterr().out)  # with --json -, stdout holds the JSON alone
    for side in ("figure", "reference"):
        s = r[side]
        assert s["episodes"] == 4 and sum(s["modes"].values()) == 4 and 0 <= s["success_rate"] <= 1
        assert 0 <= s["starts_with_both_modes"] <= 2
    assert r["figure"]["algo"] == "diffusion" and r["reference"]["algo"] == "bc" and r["png"] == str(png)
    # a missing run directory: one error line, exit 1
    assert main(["bench", "multimodal", "--diffusion", str(tmp_path / "nope"), "--reference", str(tmp_path / "bc"),
                 "--png", str(png)]) == 1


def test_bench_samplers_times_every_sampler_and_rolls_out_runs(tmp_path) -> None:
    """`demo bench samplers`: MSE, diffusion and flow at each --steps timed in the same run; a flow run rolled out at
    every step count; a run given under another algorithm's name, or a bad step list, is one line."""
    from demo.cli.main import main
    from demo.collect.scripted import CollectConfig, collect_scripted

    collect_scripted(CollectConfig(task="reach", episodes=6, seed=0), tmp_path / "r.zarr", workers=0)
    assert main(["train", str(tmp_path / "r.zarr"), "--algo", "flow", "--steps", "30", "--out", str(tmp_path / "flow"),
                 "--policy-opt", "width=32", "--policy-opt", "depth=1"]) == 0
    out = tmp_path / "s.json"
    assert main(["bench", "samplers", "--seconds", "0.05", "--steps", "1,3", "--run", f"flow={tmp_path / 'flow'}",
                 "--episodes", "2", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert set(r["ms_per_chunk"]) == {"mse", "diffusion", "flow-1", "flow-3"} and r["ratio_to_reference"]["diffusion"] == 1
    assert set(r["success"]) == {"flow-1", "flow-3"} and r["success"]["flow-3"]["episodes"] == 2
    assert main(["bench", "samplers", "--run", f"diffusion={tmp_path / 'flow'}", "--seconds", "0.01"]) == 1
    assert main(["bench", "samplers", "--steps", "0"]) == 1
