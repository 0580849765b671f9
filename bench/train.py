"""`demo bench train`: training throughput, data pipeline included, against the model's own compute.

State (default). Figure: samples/s of BC training exactly as ``demo train --algo bc`` runs it:
windows sampled from the store's frames in memory (:class:`demo.training.data.Windows`: WindowSampler
gather, relative actions, normalisation, tensors) and one optimiser step
(:func:`demo.training.optim.train_step`: forward, MSE, backward, gradient clipping, fused AdamW).
Reference, same run, same model: the bare forward + backward (no optimiser step) on batches that
are already tensors in memory. Target: ratio >= 0.8, i.e. data pipeline and optimiser together
cost at most a quarter of the model's own work. Default data: a synthetic 200k-frame store
(:func:`demo.bench.load.build_store`, 40-dim state, 8-dim actions).

Images (``--images``). Figure: samples/s of visuomotor BC training as ``demo train`` runs it on a
store with cameras: uint8 image windows gathered from the store's frames in memory, to tensors,
to the device, the encoder's uint8 -> float scaling and per-sample random crop, forward (encoders,
spatial softmax, proprioception, policy head), loss, backward, clipping, AdamW. Reference, same run,
same model: the bare forward + backward of the network on float images already scaled, cropped to
the crop size and on the device, i.e. the network's own compute and nothing else. Target: ratio
>= 0.7. Default data: a synthetic store with two 64x64 cameras (smooth images, written through
:class:`EpisodeStore`, so compression and loading are the real path); ``--data`` measures a real store.

Both: 64 distinct batches cycled (fewer for images where 64 would not fit in
:data:`REFERENCE_BYTES`; one batch repeated is overfitted within seconds, its gradients shrink into
denormal floats and the step slows down for no reason of its own); every measurement runs in
short turns, round after round, so a noisy neighbour on a shared machine hits them all alike, and
each figure is its best round (the mean over rounds is reported too). The full step on in-memory
tensors (isolating the data pipeline) and window sampling alone are reported as well. On CUDA,
forward and loss run under bfloat16 autocast in figure and reference alike, and each round ends
with a device synchronisation, so queued kernels are counted in the round that launched them.
"""

from __future__ import annotations

import itertools
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from demo.bench.common import machine, rate
from demo.bench.load import build_store
from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.training.config import TrainConfig, for_policy
from demo.training.data import STATE, Batch, TrainingData, Windows, batch_to, prepare
from demo.policies.device import autocast, resolve_device
from demo.training.optim import Learner, make_learner, train_step
from demo.policies.policy import build_policy
from demo.policies.visuomotor import VisuomotorPolicy, encoder_config

TARGET_RATIO = 0.8
TARGET_RATIO_IMAGES = 0.7
ROUNDS = 8  # turns of each measurement
BATCHES = 64  # distinct in-memory batches, cycled
REFERENCE_BYTES = 512 * 2**20  # cap on the reference's float images held in memory (fewer batches beyond it)
CAMERAS = ("front", "wrist")  # the synthetic image store's cameras
EPISODE_LENGTH = 200  # frames per synthetic episode


def run(
    data: Path | None = None,
    seconds: float = 5.0,
    batch_size: int = 256,
    chunk: int = 1,
    n_obs: int = 1,
    hidden: tuple[int, ...] = (512, 512, 512),
    threads: int = 1,
    frames: int = 200_000,
    seed: int = 0,
    device: str = "auto",
) -> dict[str, Any]:
    """State BC: training samples/s with the real pipeline vs the model's bare forward/backward."""
    dev = _start(threads, seed, device)
    config, training, setup_s = _prepare(
        data, lambda path: build_store(path, frames, EPISODE_LENGTH, 40, seed).close(), seed,
        dict(batch_size=batch_size, chunk=chunk, n_obs=n_obs, policy={"hidden": hidden}))
    if training.images:
        raise DemoError(str(data), "has camera images (obs.image_*): measure training on them with --images")
    learner = make_learner(build_policy("bc", training.spec, {"hidden": hidden}), config, device=dev)
    policy = learner.policy
    source = training.windows(training.train_episodes)
    rng = np.random.default_rng(seed)
    batches = [batch_to(source.sample(batch_size, rng), dev) for _ in range(BATCHES)]
    figures = _measure(learner, source, rng, batch_size, seconds, batches, lambda i: policy.loss(*batches[i]), TARGET_RATIO)
    return {
        "benchmark": "train",
        "data": str(data) if data else f"synthetic store, {frames} frames, 40-dim obs, 8-dim actions",
        "frames": int(len(training.obs)),
        "model": {"algo": "bc", "hidden": list(hidden), "parameters": _parameters(policy),
                  "obs_dim": training.spec.obs_dim, "action_dim": training.spec.action_dim, "n_obs": n_obs, "chunk": chunk},
        "batch": batch_size,
        **_device_record(dev),
        "setup_s": setup_s,
        "figure": "BC training (windows sampled from the store's frames, relative actions, normalisation, "
                  "forward, backward, clipping, fused AdamW)",
        "reference": "the same model's bare forward + backward (no optimiser) on batches already in memory as tensors",
        **figures,
        "machine": machine(),
    }


def run_images(
    data: Path | None = None,
    seconds: float = 30.0,
    batch_size: int | None = None,
    encoder: str = "small",
    chunk: int | None = None,
    n_obs: int | None = None,
    hidden: tuple[int, ...] | None = None,
    threads: int = 1,
    frames: int = 10_000,
    image_size: int = 64,
    seed: int = 0,
    device: str = "auto",
) -> dict[str, Any]:
    """Visuomotor BC: training samples/s through the image pipeline vs the network's bare compute.

    ``batch_size``, ``chunk``, ``n_obs`` and ``hidden`` default (None) to what ``demo train`` uses.
    """
    dev = _start(threads, seed, device)
    try:
        encoder_config({"backbone": encoder})
    except ValueError as exc:
        raise DemoError("--encoder", str(exc)) from None
    given = dict(batch_size=batch_size, chunk=chunk, n_obs=n_obs, encoder={"backbone": encoder},
                 policy={"hidden": hidden} if hidden else {})
    config, training, setup_s = _prepare(
        data, lambda path: build_image_store(path, frames, image_size, seed).close(), seed, given)
    if not training.images:
        raise DemoError(str(data), "has no camera images (obs.image_*) to benchmark --images on")
    learner = make_learner(build_policy("bc", training.spec, config.policy, config.encoder), config, device=dev)
    policy, batch = learner.policy.train(), config.batch_size
    source = training.windows(training.train_episodes)
    rng = np.random.default_rng(seed)

    # The same windows twice: as the pipeline hands them over (uint8, for the full step) and as the
    # network's input (float, scaled and cropped by the encoders' own code, for the reference).
    first = batch_to(source.sample(batch, rng), dev)
    count = max(2, min(BATCHES, REFERENCE_BYTES // max(1, _float_bytes(policy, first))))
    steps = [first, *(batch_to(source.sample(batch, rng), dev) for _ in range(count - 1))]
    bare = [_network_input(policy, b) for b in steps]
    figures = _measure(learner, source, rng, batch, seconds, steps, lambda i: _bare_loss(policy, *bare[i]), TARGET_RATIO_IMAGES)
    encoders = sum(_parameters(m) for m in policy.cameras.values())
    return {
        "benchmark": "train-images",
        "data": str(data) if data else (f"synthetic store, {frames} frames, cameras {', '.join(CAMERAS)} "
                                        f"{image_size}x{image_size}, 8-dim proprioception, 8-dim actions"),
        "frames": int(len(training.obs)),
        "cameras": {key: {"image": [h, w], "crop": list(enc.augment.crop)}
                    for (key, h, w), enc in zip(training.spec.images, policy.cameras.values())},
        "model": {"algo": "bc", "encoder": dict(config.encoder), "hidden": list(policy.head.config.hidden),
                  "parameters": _parameters(policy), "encoder_parameters": encoders, "obs_dim": training.spec.obs_dim,
                  "action_dim": training.spec.action_dim, "n_obs": config.n_obs, "chunk": config.chunk},
        "batch": batch,
        **_device_record(dev),
        "setup_s": setup_s,
        "figure": "visuomotor BC training (uint8 image windows gathered from the store's frames, tensors, to the "
                  "device, uint8 -> float, random crop, encoders + head forward, backward, clipping, fused AdamW)",
        "reference": "the same network's bare forward + backward (no optimiser) on float images already scaled, "
                     "cropped and on the device",
        "reference_batches": count,
        **figures,
        "machine": machine(),
    }


def build_image_store(path: Path, frames: int, size: int = 64, seed: int = 0) -> EpisodeStore:
    """A store of ``frames`` frames (episodes of :data:`EPISODE_LENGTH`) with :data:`CAMERAS` at
    ``size x size``, 7 joint positions + gripper and 8-dim joint-position actions.

    Images are smooth (a colour gradient per episode and camera, a square that moves across it), so
    they compress like renders rather than noise; their content is irrelevant to a throughput figure.
    """
    arm = tuple(f"joint{i}" for i in range(1, 8))
    features = {
        "obs.joint_pos": FeatureSpec((7,), "float32", "arm joint positions", "rad", arm),
        "obs.gripper": FeatureSpec((1,), "float32", "gripper closedness (0 open, 1 closed)", "1"),
        **{f"obs.image_{c}": FeatureSpec((size, size, 3), "uint8", f"camera '{c}' RGB (synthetic)", "") for c in CAMERAS},
    }
    meta = StoreMeta(fps=20.0, features=features, action=ActionSpec("joint_pos", (*arm, "gripper"), ("rad",) * 7 + ("1",)),
                     task={"name": "bench"})
    store = EpisodeStore.create(path, meta, overwrite=True)
    rng = np.random.default_rng(seed)
    grid = np.linspace(0.0, 1.0, size, dtype=np.float32)
    t = np.linspace(0.0, 1.0, EPISODE_LENGTH, dtype=np.float32)[:, None, None]
    for _ in range(max(1, frames // EPISODE_LENGTH)):
        joints = np.cumsum(rng.normal(0, 0.01, (EPISODE_LENGTH, 7)), axis=0).astype(np.float32)
        episode = {"obs.joint_pos": joints, "obs.gripper": (t[:, 0] > 0.5).astype(np.float32),
                   "action": np.concatenate([joints + 0.01, (t[:, 0] > 0.45).astype(np.float32)], axis=1)}
        for camera in CAMERAS:
            colour = rng.uniform(40, 200, (2, 3)).astype(np.float32)
            background = grid[None, :, None] * colour[0] + grid[::-1, None, None] * colour[1] / 2  # [H, W, 3]
            y0, x0, y1, x1 = rng.uniform(0.1, 0.9, 4)
            cy, cx = (y0 + (y1 - y0) * t) * size, (x0 + (x1 - x0) * t) * size  # [T, 1, 1] pixels
            square = (np.abs(np.arange(size)[None, :, None] - cy) < size / 8) & (np.abs(np.arange(size)[None, None, :] - cx) < size / 8)
            images = np.where(square[..., None], np.float32(230.0), background[None])
            episode[f"obs.image_{camera}"] = images.astype(np.uint8)
        store.append_episodes([(episode, {"success": True, "source": "synthetic"})])
    return store


def _start(threads: int, seed: int, device: str) -> torch.device:
    """Threads and seed set; the device ``--device`` names (a DemoError for one this machine lacks)."""
    dev = resolve_device(device)
    if threads > 0:
        torch.set_num_threads(threads)
    torch.manual_seed(seed)
    return dev


def _prepare(data: Path | None, build: Callable[[Path], None], seed: int,
             given: dict[str, Any]) -> tuple[TrainConfig, TrainingData, float]:
    """The resolved BC config, the training data of ``data`` (or of a store ``build`` writes) and the
    seconds from opening the store to windows ready (load, split, normalisers)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(data) if data else Path(tmp) / "bench.zarr"
        if data is None:
            build(path)
        config = for_policy("bc", data=str(path), out=str(Path(tmp) / "run"), seed=seed, include_failures=True, **given)
        config.check()
        t0 = time.perf_counter()
        with EpisodeStore.open(path) as store:
            training = prepare(config, store)
        return config, training, time.perf_counter() - t0


def _network_input(policy: VisuomotorPolicy, batch: Batch) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    """A batch as the network proper receives it: state, each camera's float images after the
    encoder's own scaling and crop (:meth:`VisuomotorPolicy.preprocess`, made contiguous), action, padding."""
    obs, action, pad = batch
    with torch.no_grad():
        crops = {key: x.contiguous() for key, x in policy.preprocess(obs).items()}
    return obs[STATE], crops, action, pad


def _bare_loss(policy: VisuomotorPolicy, state: torch.Tensor, crops: dict[str, torch.Tensor], action: torch.Tensor,
               pad: torch.Tensor) -> torch.Tensor:
    """The visuomotor loss from :func:`_network_input`'s tensors: the policy's loss without the
    uint8 -> float scaling and the crop (:meth:`VisuomotorPolicy.fuse`, then the head's loss)."""
    return policy.head.loss(policy.fuse(state, crops), action, pad)


def _float_bytes(policy: VisuomotorPolicy, batch: Batch) -> int:
    """Bytes of one batch's cropped float32 images (what the reference holds per batch)."""
    obs = batch[0]
    return sum(obs[key].shape[0] * obs[key].shape[1] * 3 * enc.augment.crop[0] * enc.augment.crop[1] * 4
               for key, enc in zip(policy.keys, policy.cameras.values()))


def _interleaved(steps: dict[str, Callable[[], Any]], batch: int, seconds: float,
                 device: torch.device) -> dict[str, dict[str, float]]:
    """Samples/s of each step, measured in :data:`ROUNDS` rounds of turns of ``seconds / (ROUNDS * steps)``
    (at least one call each). One warm-up call each first (autotuning, caches, lazy allocation)."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for fn in steps.values():
        fn()
    sync()
    turn_s = seconds / (ROUNDS * len(steps))
    rounds: dict[str, list[tuple[int, float]]] = {name: [] for name in steps}
    for _ in range(ROUNDS):
        for name, fn in steps.items():
            calls, t0 = 0, time.perf_counter()
            while calls == 0 or time.perf_counter() - t0 < turn_s:
                fn()
                calls += 1
            sync()
            rounds[name].append((calls, time.perf_counter() - t0))
    return {name: {"best_round_per_s": max(c * batch / s for c, s in r),
                   "mean_per_s": sum(c for c, _ in r) * batch / sum(s for _, s in r),
                   "calls": sum(c for c, _ in r), "seconds": sum(s for _, s in r)} for name, r in rounds.items()}


def _measure(learner: Learner, source: Windows, rng: np.random.Generator, batch: int, seconds: float,
             batches: list[Batch], reference_loss: Callable[[int], torch.Tensor], target: float) -> dict[str, Any]:
    """The JSON's figures: training steps on sampled windows (the figure), full steps on the in-memory
    ``batches`` and the reference, forward + backward of ``reference_loss(i)`` on the ``i``-th in-memory
    input (both cycled), timed in turn (:func:`_interleaved`); then window sampling alone."""
    policy, device = learner.policy, learner.device
    turn = itertools.cycle(range(len(batches)))

    def forward_backward() -> None:
        policy.zero_grad(set_to_none=True)
        with autocast(device):
            loss = reference_loss(next(turn))
        loss.backward()

    timed = _interleaved({
        "pipeline": lambda: train_step(learner, *source.sample(batch, rng)),
        "step": lambda: train_step(learner, *batches[next(turn)]),
        "bare": forward_backward,
    }, batch, seconds, device)
    pipe, step, bare = (timed[k]["best_round_per_s"] for k in ("pipeline", "step", "bare"))
    return {
        "samples_per_s": pipe,
        "reference_samples_per_s": bare,
        "ratio_to_reference": pipe / bare,
        "in_memory_step_samples_per_s": step,
        "ratio_to_in_memory_step": pipe / step,
        "statistic": f"best of {ROUNDS} interleaved rounds (mean_*: over all rounds)",
        "mean_samples_per_s": timed["pipeline"]["mean_per_s"],
        "mean_reference_samples_per_s": timed["bare"]["mean_per_s"],
        "mean_ratio_to_reference": timed["pipeline"]["mean_per_s"] / timed["bare"]["mean_per_s"],
        "target_ratio": target,
        "meets_target": pipe / bare >= target,
        "sampling_only_samples_per_s": rate(lambda: source.sample(batch, rng), batch, min(2.0, seconds / 8))["per_s"],
    }


def _device_record(device: torch.device) -> dict[str, Any]:
    return {
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else None,
        "autocast": "bfloat16" if device.type == "cuda" else None,
        "torch_threads": torch.get_num_threads(),
    }


def _parameters(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
