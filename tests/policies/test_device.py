"""`--device`: resolution everywhere; on a CUDA GPU, a tiny image policy trains under bf16 autocast.

The GPU tests run where torch sees a CUDA GPU and are skipped, saying why, where it does not (CI).
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.bench.train import build_image_store
from demo.cli.main import main
from demo.errors import DemoError
from demo.store import EpisodeStore
from demo.training.config import for_policy
from demo.training.data import prepare
from demo.policies.device import autocast, resolve_device
from demo.training.optim import make_learner, train_step
from demo.policies.policy import build_policy

pytestmark = pytest.mark.usefixtures("torch_one_thread")
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine")


def test_resolve_device() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    auto = resolve_device("auto").type
    assert auto == "cuda" if torch.cuda.is_available() else auto in ("mps", "cpu")
    with pytest.raises(DemoError, match="unknown device 'tpu'"):
        resolve_device("tpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_cuda_without_a_gpu_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(DemoError, match="no CUDA GPU"):
        resolve_device("cuda")
    for bench in (["train", "--images"], ["infer"]):
        assert main(["bench", *bench, "--device", "cuda", "--json", "-"]) == 1
        err = capsys.readouterr().err
        assert "--device" in err and "no CUDA GPU" in err and "Traceback" not in err


def test_autocast_is_bf16_on_cuda_only() -> None:
    assert isinstance(autocast(torch.device("cpu")), contextlib.nullcontext)


@pytest.fixture(scope="module")
def image_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("device") / "img.zarr"
    build_image_store(path, 800, 32, seed=0).close()
    return path


def _train(store: Path, out: Path, device: str, steps: int = 4) -> tuple[list[torch.Tensor], dict, dict]:
    """``steps`` optimiser steps of a tiny image BC policy on ``device``: losses, weights before and after."""
    config = for_policy("bc", data=str(store), out=str(out), batch_size=16, chunk=4, policy={"hidden": (32,)},
                        include_failures=True, device=device)
    with EpisodeStore.open(store) as s:
        data = prepare(config, s)
    torch.manual_seed(0)
    learner = make_learner(build_policy("bc", data.spec, config.policy, config.encoder), config, device=resolve_device(device))
    assert all(p.device.type == device for p in learner.policy.parameters())
    before = {k: v.detach().clone() for k, v in learner.policy.state_dict().items()}
    windows, rng = data.windows(data.train_episodes), np.random.default_rng(0)
    losses = [train_step(learner, *windows.sample(16, rng)) for _ in range(steps)]
    return losses, before, learner.policy.state_dict()


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=needs_cuda)])
def test_image_policy_trains_on_the_device(device: str, image_store: Path, tmp_path: Path) -> None:
    losses, before, after = _train(image_store, tmp_path / "run", device)
    assert all(loss.device.type == device and torch.isfinite(loss) for loss in losses)
    assert all(after[k].dtype == torch.float32 for k, v in before.items() if v.dtype.is_floating_point)  # weights stay fp32
    assert any(not torch.equal(before[k], after[k]) for k in before)  # the optimiser stepped
    if device == "cpu":  # deterministic for its seed
        assert torch.equal(torch.stack(losses), torch.stack(_train(image_store, tmp_path / "again", device)[0]))
    else:
        with autocast(torch.device(device)):  # what train_step runs the forward under
            x = torch.ones(4, 4, device=device)
            assert (x @ x).dtype == torch.bfloat16


@needs_cuda
def test_demo_train_and_bench_on_cuda(image_store: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert main(["train", str(image_store), "--out", str(run), "--steps", "3", "--batch-size", "8", "--chunk", "4",
                 "--policy-opt", "hidden=32", "--include-failures", "--device", "cuda"]) == 0
    assert (run / "policy.safetensors").is_file()
    out = tmp_path / "bench.json"
    assert main(["bench", "train", "--images", "--data", str(image_store), "--seconds", "0.5", "--batch-size", "16",
                 "--device", "cuda", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["device"].startswith("cuda") and r["autocast"] == "bfloat16" and r["samples_per_s"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=needs_cuda)])
def test_bench_infer_on_the_device(device: str, tmp_path: Path) -> None:
    out = tmp_path / "infer.json"
    assert main(["bench", "infer", "--denoiser", "mlp", "--inference-steps", "2", "--seconds", "0.02",
                 "--device", device, "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["device"].startswith(device) and r["ms_per_chunk"] > 0
