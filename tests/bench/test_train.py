"""`demo bench train --images` (and `--device`): the image pipeline against the network's bare compute."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.bench.load import build_store
from demo.bench.train import _bare_loss, _network_input, _prepare, build_image_store
from demo.cli.main import main
from demo.policies.policy import build_policy

pytestmark = pytest.mark.usefixtures("torch_one_thread")
TINY = ["--frames", "1000", "--image-size", "32", "--seconds", "0.2", "--batch-size", "8", "--hidden", "16"]


@pytest.mark.slow
def test_bench_train_images_writes_figure_reference_and_ratio(capfd: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "train", "--images", *TINY, "--device", "cpu", "--json", "-"]) == 0
    out, err = capfd.readouterr()
    r = json.loads(out)  # stdout holds only the JSON; the table went to stderr
    assert "met" in err and "ratio" in err
    assert r["benchmark"] == "train-images" and r["device"] == "cpu" and r["autocast"] is None
    assert r["samples_per_s"] > 0 and r["reference_samples_per_s"] > 0
    assert r["ratio_to_reference"] == pytest.approx(r["samples_per_s"] / r["reference_samples_per_s"])
    assert r["meets_target"] == (r["ratio_to_reference"] >= r["target_ratio"] == 0.7)
    assert "random crop" in r["figure"] and "bare forward + backward" in r["reference"]
    assert r["cameras"] == {f"obs.image_{c}": {"image": [32, 32], "crop": [28, 28]} for c in ("front", "wrist")}
    assert r["batch"] == 8 and r["frames"] == 1000 and r["reference_batches"] == 64
    assert r["model"]["encoder"] == {"backbone": "small"} and r["model"]["hidden"] == [16]
    assert 0 < r["model"]["encoder_parameters"] < r["model"]["parameters"]


def test_bench_train_records_the_device(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "train", "--frames", "2000", "--seconds", "0.2", "--hidden", "16", "--batch-size", "32",
                 "--device", "cpu", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["benchmark"] == "train" and r["device"] == "cpu" and r["target_ratio"] == 0.8


def test_the_reference_computes_the_same_network() -> None:
    """The reference's pre-scaled, pre-cropped input through backbone, keypoints and head gives the
    loss the policy computes from the uint8 batch (centre crop, so both crops agree)."""
    config, data, _ = _prepare(None, lambda path: build_image_store(path, 600, 24, 0).close(), 0,
                               {"batch_size": 4, "chunk": 2, "policy": {"hidden": (8,)}})
    policy = build_policy("bc", data.spec, config.policy, config.encoder).eval()
    batch = data.windows(data.train_episodes).sample(4, np.random.default_rng(0))
    with torch.no_grad():
        expected = policy.loss(*batch)
        assert _bare_loss(policy, *_network_input(policy, batch)).item() == pytest.approx(expected.item(), rel=1e-5)


def test_synthetic_image_store_goes_through_the_real_store(tmp_path: Path) -> None:
    with build_image_store(tmp_path / "img.zarr", 400, 16, seed=3) as store:
        arrays, ends = store.load(["obs.image_front", "obs.image_wrist", "obs.joint_pos"])
    assert list(ends) == [200, 400]
    front = arrays["obs.image_front"]
    assert front.shape == (400, 16, 16, 3) and front.dtype == np.uint8
    assert not np.array_equal(front, arrays["obs.image_wrist"]) and front.std() > 10  # not blank


@pytest.mark.parametrize("args, message", [
    (["--images", "--encoder", "vit"], "--encoder"),
    (["--device", "tpu"], "unknown device 'tpu'"),
    (["--encoder", "small"], "applies to --images only"),
    (["--images", "--hidden", "16,x"], "--hidden"),
])
def test_bad_flags_are_one_line_errors(args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "train", *args, "--json", "-"]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_images_on_a_store_without_cameras_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "state.zarr"
    build_store(path, frames=600, episode_length=100, obs_dim=4).close()
    assert main(["bench", "train", "--images", "--data", str(path), "--seconds", "0.1", "--json", "-"]) == 1
    err = capsys.readouterr().err
    assert "has no camera images" in err and str(path) in err and "Traceback" not in err


def test_state_benchmark_on_a_store_with_cameras_points_to_images(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "img.zarr"
    build_image_store(path, 400, 16).close()
    assert main(["bench", "train", "--data", str(path), "--seconds", "0.1", "--json", "-"]) == 1
    err = capsys.readouterr().err
    assert "--images" in err and str(path) in err and "Traceback" not in err
