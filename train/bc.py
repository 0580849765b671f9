"""Behaviour cloning: supervised training of a registered policy on demonstration windows.

``demo train DATA --algo bc`` (and ``--algo diffusion``, whose policy only brings another loss)
runs :func:`train`, which reads top to bottom:

1. **data**: the store's low-dim ``obs.*`` keys are concatenated per frame (:class:`ObsSpec`);
   episodes are split into training and validation (a store mask ``--val-mask``, or a seeded random
   ``--val-fraction`` of the episodes); failed episodes are left out unless ``include_failures``;
2. **normalisers**: min-max to [-1, 1] for observations and actions, fitted on the training frames
   and stored with the policy;
3. **windows**: :class:`demo.store.WindowSampler` over the normalised arrays gives observation
   histories ``[B, n_obs, D]`` and action chunks ``[B, chunk, A]``, padded at episode edges;
4. **optimisation**: AdamW, linear warm-up then cosine decay to ``min_lr_ratio * lr``, gradient
   clipping, optional EMA of the weights (evaluation uses the EMA weights);
5. **monitoring**: mean training loss every ``log_every`` steps, validation loss every
   ``val_every`` steps, rollout success every ``eval_every`` steps (``eval_episodes`` episodes on
   the store's task, seeds disjoint from the data), a rich progress bar, ``metrics.json`` and
   ``curves.png``;
6. **checkpoints**: the run directory of :mod:`demo.train.checkpoint`, saved at every evaluation
   and at the end; ``resume`` continues a run from ``train_state.pt`` exactly where it stopped.

The loss is the policy's own (:meth:`Policy.loss`): MSE for the MLP. Everything is seeded: the
same config and data give the same weights.
"""

from __future__ import annotations

import copy
import json
import math
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, WindowSampler
from demo.train import checkpoint as ckpt
from demo.train.actor import ExecConfig
from demo.train.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.train.observation import ObsSpec
from demo.train.policy import Policy, PolicySpec, build_policy, policy_config
from demo.train.progress import TrainProgress
from demo.train.relative import RelativeActions, default_relative

LABEL_KEY = "info.labelled"  # optional per-frame flag: this frame's action is an expert label


@dataclass
class TrainConfig:
    """Every hyperparameter of a behaviour-cloning run."""

    data: str = ""  # episode store
    out: str = ""  # run directory
    algo: str = "bc"  # registered policy (demo.train.policy): bc (MLP), diffusion, ...
    policy: dict[str, Any] = field(default_factory=dict)  # the policy's Config fields, e.g. {"hidden": (256, 256)}
    seed: int = 0
    steps: int = 5000
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 500
    min_lr_ratio: float = 0.01  # cosine decays to this fraction of lr
    grad_clip: float = 10.0  # max gradient norm; 0 = off
    ema: float = 0.0  # EMA decay of the weights (e.g. 0.999); 0 = off
    n_obs: int = 1  # observation history (frames)
    chunk: int = 1  # actions predicted per query (action chunking when > 1)
    execute: int = 1  # actions executed per query
    ensemble: float | None = None  # temporal ensembling decay (ACT: 0.01); None = off
    binary_gripper: bool = False  # execute the action's "gripper" entry as open/closed (>= 0.5: 1), see ExecConfig.binary
    obs_keys: tuple[str, ...] = ()  # default: low-dim obs.* keys except velocities (demo.train.observation); ("all",) = all
    obs_noise: float = 0.0  # std of Gaussian noise added to normalised observations (augmentation)
    relative_actions: bool = True  # predict joint targets relative to the current joint positions (demo.train.relative)
    train_mask: str | None = None  # train on this store mask's episodes only (e.g. a curated subset)
    val_mask: str | None = None  # validation episodes = this mask's episodes
    val_fraction: float = 0.1  # otherwise this fraction of episodes, drawn with the seed
    include_failures: bool = False  # also train on episodes whose success is False
    log_every: int = 100
    val_every: int = 500
    eval_every: int = 0  # rollout evaluation every N steps; 0 = only if eval_final
    eval_episodes: int = 10
    eval_final: bool = False  # evaluate once more at the end
    threads: int = 1  # torch threads (small networks gain little from more; idle threads busy-wait on a shared machine); 0 = torch's default

    def check(self) -> None:
        positive = {"steps": self.steps, "batch_size": self.batch_size, "n_obs": self.n_obs, "chunk": self.chunk,
                    "execute": self.execute, "log_every": self.log_every, "val_every": self.val_every}
        for name, value in positive.items():
            if value < 1:
                raise DemoError(f"--{name.replace('_', '-')}", f"must be at least 1, got {value}")
        if self.execute > self.chunk:
            raise DemoError("--execute", f"cannot exceed --chunk ({self.chunk}), got {self.execute}")
        if not 0 <= self.val_fraction < 1:
            raise DemoError("--val-fraction", f"must lie in [0, 1), got {self.val_fraction}")
        if not 0 <= self.ema < 1:
            raise DemoError("--ema", f"must lie in [0, 1), got {self.ema}")
        if self.lr <= 0:
            raise DemoError("--lr", f"must be > 0, got {self.lr}")
        if self.ensemble is not None and self.ensemble < 0:
            raise DemoError("--ensemble", f"must be >= 0, got {self.ensemble}")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["obs_keys"] = list(self.obs_keys)
        d["policy"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.policy.items()}
        return d


# ================================================================================== 1-3. data
@dataclass
class Dataset:
    """A store's frames in memory, with the split. Actions stay raw: their normalised form depends on
    the window's query frame when they are relative (:mod:`demo.train.relative`)."""

    obs: np.ndarray  # [N, D] normalised observations
    action: np.ndarray  # [N, A] raw actions (the store's representation and units)
    base: np.ndarray | None  # [N, A] subtracted from the actions of windows queried at each frame; None = absolute
    action_norm: MinMaxNormalizer | None  # of (relative) actions; set by :func:`setup`
    ends: np.ndarray  # episode ends (every store episode)
    train_episodes: np.ndarray
    val_episodes: np.ndarray
    labelled: np.ndarray | None  # [N] bool, frames holding an expert label; None = every frame

    def frames(self, episodes: np.ndarray) -> int:
        starts = np.concatenate([[0], self.ends[:-1]])
        if self.labelled is None:
            return int((self.ends[episodes] - starts[episodes]).sum())
        return int(sum(self.labelled[starts[i] : self.ends[i]].sum() for i in episodes))


def split_episodes(
    store: EpisodeStore, config: TrainConfig, among: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation episode indices (disjoint, sorted), from ``among`` (default: all)."""
    candidates = store.select(config.train_mask) if config.train_mask else np.arange(store.num_episodes)
    if among is not None:
        candidates = np.intersect1d(candidates, among)
    if not config.include_failures and store.num_episodes:
        ok = store.column("success").astype(bool)
        candidates = candidates[ok[candidates]]
    if config.val_mask:
        val = np.intersect1d(store.select(config.val_mask), np.arange(store.num_episodes))
        train = np.setdiff1d(candidates, val)
    else:
        n_val = int(round(config.val_fraction * len(candidates)))
        if config.val_fraction > 0 and len(candidates) >= 4:
            n_val = max(1, n_val)
        perm = np.random.default_rng([config.seed, 0x5E1]).permutation(len(candidates))
        val = np.sort(candidates[perm[:n_val]])
        train = np.sort(candidates[perm[n_val:]])
    if len(train) == 0:
        raise DemoError(store.path, "has no episodes left to train on (check --train-mask/--val-mask/--include-failures)")
    return train, np.sort(val)


@dataclass
class RawData:
    obs: np.ndarray  # [N, D] concatenated observations
    action: np.ndarray  # [N, A]
    base: np.ndarray | None  # [N, A] relative-action base per frame
    ends: np.ndarray
    labelled: np.ndarray | None

    def dataset(self, obs_norm: MinMaxNormalizer, action_norm: MinMaxNormalizer | None, train: np.ndarray,
                val: np.ndarray) -> Dataset:
        obs = np.clip(obs_norm.normalize(self.obs), -OBS_CLIP, OBS_CLIP)  # as the actor does in rollouts
        return Dataset(obs, self.action, self.base, action_norm, self.ends, train, val,
                       self.labelled)


def load_raw(store: EpisodeStore, obs_spec: ObsSpec, relative: RelativeActions | None) -> RawData:
    """Concatenated observations, actions, relative-action bases, episode ends, label flags."""
    keys = [*obs_spec.source_keys, "action"] + ([LABEL_KEY] if LABEL_KEY in store.meta.features else [])
    if relative is not None and relative.obs_key not in keys:
        keys.append(relative.obs_key)
    data, ends = store.load(keys)
    labelled = data[LABEL_KEY].reshape(-1).astype(bool) if LABEL_KEY in data else None
    action = np.asarray(data["action"], dtype=np.float32)
    base = relative.base(data, action.shape[1]) if relative is not None else None
    return RawData(obs_spec.concat(data), action, base, ends, labelled)


def fit_action_normalizer(data: Dataset, episodes: np.ndarray, n_obs: int, horizon: int) -> MinMaxNormalizer:
    """Min-max over every action of every training window (chunk steps included), in blocks."""
    source = BatchSource(data, episodes, n_obs, horizon)
    lo = np.full(data.action.shape[1], np.inf, np.float32)
    hi = np.full(data.action.shape[1], -np.inf, np.float32)
    idx = source.sampler.indices
    for i in range(0, len(idx), 65536):
        block = source.raw_actions(idx[i : i + 65536]).reshape(-1, data.action.shape[1])
        lo, hi = np.minimum(lo, block.min(axis=0)), np.maximum(hi, block.max(axis=0))
    return MinMaxNormalizer.from_limits(lo, hi)


def frame_indices(ends: np.ndarray, episodes: np.ndarray) -> np.ndarray:
    starts = np.concatenate([[0], ends[:-1]])
    return np.concatenate([np.arange(starts[i], ends[i]) for i in episodes]) if len(episodes) else np.zeros(0, np.int64)


class BatchSource:
    """Random training windows as tensors: the WindowSampler on in-memory arrays, then actions made
    relative to the query frame (if so) and normalised, a few array operations per batch.

    With per-frame label flags (HG-DAgger stores only the expert's interventions as labels), windows
    start at labelled frames only, and chunk steps on unlabelled frames count as padding (no loss).
    """

    def __init__(self, data: Dataset, episodes: np.ndarray, n_obs: int, horizon: int):
        partial = data.labelled is not None and not data.labelled.all()
        # The flag rides along as an extra action column, so one gather serves both.
        action = np.concatenate([data.action, data.labelled[:, None].astype(np.float32)], axis=1) if partial else data.action
        self.sampler = WindowSampler(
            {"obs": data.obs, "action": action}, data.ends, ["obs"], "action", n_obs, horizon, episodes=episodes
        )
        if data.labelled is not None:
            self.sampler.indices = self.sampler.indices[data.labelled[self.sampler.indices]]
        self.partial = partial
        self.base, self.norm = data.base, data.action_norm

    def __len__(self) -> int:
        return len(self.sampler)

    def _window(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        b = self.sampler.get(t)
        action, pad = b.action, b.action_pad
        if self.partial:
            action, pad = action[..., :-1], pad | (action[..., -1] < 0.5)
        if self.base is not None:
            action = action - self.base[b.index][:, None, :]
        return b.obs["obs"], action, pad

    def raw_actions(self, t: np.ndarray) -> np.ndarray:
        """``[B, H, A]`` actions of the windows at ``t``, relative to their query frame if so."""
        return self._window(t)[1]

    def get(self, t: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        obs, action, pad = self._window(t)
        action = self.norm.normalize(action) if self.norm is not None else action
        return torch.from_numpy(obs), torch.from_numpy(np.ascontiguousarray(action)), torch.from_numpy(pad)

    def sample(self, batch_size: int, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.get(self.sampler.indices[rng.integers(0, len(self.sampler.indices), size=batch_size)])

    def fixed(self, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
        """Up to ``n`` windows chosen once (validation), or None when there are none."""
        if len(self.sampler) == 0:
            return None
        idx = self.sampler.indices
        if len(idx) > n:
            idx = np.sort(np.random.default_rng(seed).choice(idx, size=n, replace=False))
        return self.get(idx)


def execution_config(config: TrainConfig, action: ActionSpec) -> ExecConfig:
    """How the trained policy's chunks and gripper are executed (recorded in the run)."""
    binary = tuple(i for i, name in enumerate(action.names) if name == "gripper") if config.binary_gripper else ()
    return ExecConfig(config.execute, config.ensemble, binary)


# ================================================================================== 4. optimisation
class EMA:
    """Exponential moving average of a model's floating-point weights, with the usual warm-up
    (decay ``min(decay, (1 + step) / (10 + step))``) so early averages are not dominated by init."""

    def __init__(self, model: torch.nn.Module, decay: float):
        self.decay = decay
        self.shadow = {k: v.detach().clone() for k, v in model.state_dict().items()}

    @torch.no_grad()
    def update(self, model: torch.nn.Module, step: int) -> None:
        d = min(self.decay, (1 + step) / (10 + step))
        for k, v in model.state_dict().items():
            if v.dtype.is_floating_point:
                self.shadow[k].lerp_(v, 1.0 - d)
            else:
                self.shadow[k].copy_(v)


@dataclass
class Learner:
    """The policy being trained and everything its optimisation needs."""

    policy: Policy
    optimizer: torch.optim.Optimizer
    config: TrainConfig
    ema: EMA | None = None
    step: int = 0
    phase_start: int = 0  # the LR schedule restarts at phase_start (DAgger rounds)
    phase_steps: int = 1
    _eval_copy: Policy | None = None

    def lr_at(self, step: int) -> float:
        c = self.config
        s = step - self.phase_start
        warmup = min(c.warmup_steps, max(1, self.phase_steps // 10)) if c.warmup_steps else 0
        if s < warmup:
            return c.lr * (s + 1) / warmup
        progress = min(1.0, (s - warmup) / max(1, self.phase_steps - warmup))
        return c.lr * (c.min_lr_ratio + (1 - c.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress)))

    def eval_weights(self) -> dict[str, torch.Tensor]:
        return self.ema.shadow if self.ema is not None else self.policy.state_dict()

    def eval_policy(self) -> Policy:
        """The weights evaluation uses (EMA when on), in eval mode."""
        if self.ema is None:
            return self.policy.eval()
        if self._eval_copy is None:
            self._eval_copy = copy.deepcopy(self.policy)
        self._eval_copy.load_state_dict(self.ema.shadow)
        return self._eval_copy.eval()


def make_learner(policy: Policy, config: TrainConfig) -> Learner:
    decay, no_decay = [], []
    for name, p in policy.named_parameters():
        (no_decay if p.ndim < 2 else decay).append(p)  # no weight decay on biases and norms
    groups = [{"params": decay, "weight_decay": config.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    try:
        # The fused CPU kernel is ~10x faster than the default per-tensor loop (1 ms vs 13 ms per step
        # for a 512x3 MLP): without it the optimiser step costs half as much as forward + backward.
        optimizer = torch.optim.AdamW(groups, lr=config.lr, fused=True)
    except (RuntimeError, TypeError):
        optimizer = torch.optim.AdamW(groups, lr=config.lr, foreach=True)
    ema = EMA(policy, config.ema) if config.ema > 0 else None
    return Learner(policy, optimizer, config, ema, step=0, phase_start=0, phase_steps=config.steps)


def train_step(learner: Learner, obs: torch.Tensor, action: torch.Tensor, pad: torch.Tensor) -> torch.Tensor:
    """One optimiser step on a batch; returns the (detached) loss."""
    c = learner.config
    policy = learner.policy.train()
    lr = learner.lr_at(learner.step)
    for group in learner.optimizer.param_groups:
        group["lr"] = lr
    if c.obs_noise > 0:
        obs = obs + c.obs_noise * torch.randn_like(obs)
    loss = policy.loss(obs, action, pad)
    learner.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if c.grad_clip > 0:
        torch.nn.utils.clip_grad_norm_(policy.parameters(), c.grad_clip)
    learner.optimizer.step()
    if learner.ema is not None:
        learner.ema.update(policy, learner.step - learner.phase_start)
    learner.step += 1
    return loss.detach()


@torch.no_grad()
def validation_loss(learner: Learner, batch: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None) -> float | None:
    if batch is None:
        return None
    policy = learner.eval_policy()
    n = len(batch[0])
    # A stochastic loss (diffusion) stays comparable across steps and leaves the training RNG alone.
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        total = sum(policy.loss(*[x[i : i + 1024] for x in batch]).item() * min(1024, n - i) for i in range(0, n, 1024))
    return float(total / n)


def train_state(learner: Learner, rng: np.random.Generator, metrics: dict[str, Any], extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything --resume needs, as tensors, numbers, strings, lists and dicts only."""
    return {
        "step": learner.step,
        "phase_start": learner.phase_start,
        "phase_steps": learner.phase_steps,
        "policy": learner.policy.state_dict(),
        "ema": learner.ema.shadow if learner.ema is not None else {},
        "optimizer": learner.optimizer.state_dict(),
        "numpy_rng": json.dumps(rng.bit_generator.state),
        "torch_rng": torch.get_rng_state(),
        "metrics": json.dumps(metrics),
        "extra": json.dumps(extra or {}),
    }


def restore(learner: Learner, state: dict[str, Any], rng: np.random.Generator, where: Path) -> dict[str, Any]:
    """Load a train state into ``learner`` and ``rng``; returns the metrics recorded so far."""
    try:
        learner.policy.load_state_dict(state["policy"])
        if learner.ema is not None:
            learner.ema.shadow = {k: v.clone() for k, v in state["ema"].items()}
        learner.optimizer.load_state_dict(state["optimizer"])
        learner.step = int(state["step"])
        learner.phase_start = int(state.get("phase_start", 0))
        learner.phase_steps = int(state.get("phase_steps", learner.config.steps))
        rng.bit_generator.state = json.loads(state["numpy_rng"])
        torch.set_rng_state(state["torch_rng"])
        return json.loads(state["metrics"])
    except (KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise DemoError(where, f"train state does not match this run ({str(exc).splitlines()[0][:160]})") from None


# ================================================================================== 5. monitoring
class Monitor:
    """Periodic rollout evaluation on the data's task (seeds disjoint from the data and from demo eval)."""

    def __init__(self, episodes: int, seed: int):
        self.episodes, self.seed = episodes, seed
        self.env: Any = None

    def __call__(self, bundle: ckpt.PolicyBundle) -> dict[str, Any]:
        from demo.train.evaluate import make_eval_env, resolve_target, run_episodes_inline, summarize
        from demo.train.seeds import MONITOR_OFFSET, eval_seeds

        if self.env is None:
            task, options, robot = resolve_target(bundle, None, None, None)
            self.env = make_eval_env(bundle, task, options, robot)
        outcomes = run_episodes_inline(bundle, self.env, eval_seeds(self.seed, self.episodes, MONITOR_OFFSET))
        return summarize(outcomes)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def fit(
    learner: Learner,
    source: BatchSource,
    until: int,
    rng: np.random.Generator,
    metrics: dict[str, Any],
    val_batch: Any = None,
    bar: TrainProgress | None = None,
    on_eval: Callable[[], None] | None = None,
) -> None:
    """Optimise until ``learner.step == until``, logging into ``metrics`` (the loop all algorithms share)."""
    c = learner.config
    running, count, t0 = torch.zeros(()), 0, time.perf_counter()
    if val_batch is not None and learner.step == 0 and not metrics.get("val_loss"):
        metrics.setdefault("val_loss", []).append([0, validation_loss(learner, val_batch)])  # the untrained policy
    while learner.step < until:
        loss = train_step(learner, *source.sample(c.batch_size, rng))
        running += loss
        count += 1
        step = learner.step
        if step % c.log_every == 0 or step == until:
            mean = float(running / count)
            if not math.isfinite(mean):
                raise DemoError(c.out, f"training diverged (loss {mean} at step {step}); lower --lr")
            metrics.setdefault("train_loss", []).append([step, mean])
            rate = count * c.batch_size / max(time.perf_counter() - t0, 1e-9)
            running, count, t0 = torch.zeros(()), 0, time.perf_counter()
            if bar:
                bar.update(step, loss=mean, info=f"{rate:,.0f} samples/s")
        if val_batch is not None and (step % c.val_every == 0 or step == until):
            v = validation_loss(learner, val_batch)
            metrics.setdefault("val_loss", []).append([step, v])
            if bar:
                bar.update(step, val=v)
        if on_eval is not None and c.eval_every and step % c.eval_every == 0 and step != until:
            on_eval()


# ================================================================================== 6. the run
def prepare_run_dir(out: Path, resume: bool, overwrite: bool) -> None:
    if resume:
        if not (out / ckpt.STATE_FILE).is_file():
            raise DemoError(out, f"nothing to resume (no {ckpt.STATE_FILE})")
        return
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise DemoError(out, "already exists (pass --resume to continue it, --overwrite to replace it)")
        if not (out / ckpt.RUN_FILE).is_file():
            raise DemoError(out, "exists and is not a training run; refusing to overwrite it")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)


def check_resumable(out: Path, run: dict[str, Any]) -> None:
    """--resume must continue the same training: same data, policy and data-shaping options."""
    old = ckpt.read_run(out)
    keys = ("algo", "policy", "seed", "batch_size", "lr", "n_obs", "chunk", "obs_keys", "train_mask", "val_mask",
            "val_fraction", "include_failures", "ema", "weight_decay", "warmup_steps", "min_lr_ratio",
            "relative_actions", "obs_noise")
    a, b = old.get("train", {}), run["train"]
    differ = [k for k in keys if json.dumps(a.get(k)) != json.dumps(b.get(k))]
    if old.get("algo") != run["algo"] and "algo" not in differ:
        differ.insert(0, "algo")
    if str(Path(old.get("data", {}).get("path", ""))) != str(Path(run["data"]["path"])):
        differ.append("data")
    if differ:
        raise DemoError(out, f"cannot resume with a different {', '.join(differ)} (only --steps and monitoring may change)")


def save(
    out: Path,
    learner: Learner,
    obs_norm: MinMaxNormalizer,
    action_norm: MinMaxNormalizer,
    rng: np.random.Generator,
    metrics: dict[str, Any],
    extra: dict[str, Any] | None = None,
    title: str = "",
) -> None:
    from demo.train.plots import plot_training

    ckpt.save_policy(out, learner.eval_weights(), obs_norm, action_norm)
    ckpt.save_train_state(out, train_state(learner, rng, metrics, extra))
    ckpt.write_json(out / ckpt.METRICS_FILE, metrics)
    plot_training(metrics, out / ckpt.CURVES_FILE, title=title)


def bundle_of(learner: Learner, s: "Setup", action: ActionSpec, execution: ExecConfig, run: dict[str, Any],
              out: Path) -> ckpt.PolicyBundle:
    """The policy as it is now (evaluation weights), runnable like a saved one."""
    return ckpt.PolicyBundle(learner.config.algo, learner.eval_policy(), s.obs_spec, s.obs_norm, s.action_norm, action,
                             execution, run, out, s.relative)


def run_record(config: TrainConfig, store: EpisodeStore, s: "Setup", policy: Policy, execution: ExecConfig,
               command: str | None, algo_record: dict[str, Any] | None = None) -> dict[str, Any]:
    data = s.data
    seeds = store.column("seed") if store.num_episodes else np.zeros(0, int)
    used = np.union1d(data.train_episodes, data.val_episodes)
    return {
        "algo": (algo_record or {}).get("name", config.algo),
        "created": ckpt.now(),
        "command": command,
        "policy": ckpt.policy_record(config.algo, policy, s.obs_spec, store.meta.action, execution, s.relative),
        "task": store.meta.task,
        "robot": store.meta.robot,
        "fps": store.meta.fps,
        "data": {
            "path": str(Path(config.data).resolve()),
            "episodes_total": store.num_episodes,
            "train_episodes": data.train_episodes.tolist(),
            "val_episodes": data.val_episodes.tolist(),
            "train_frames": data.frames(data.train_episodes),
            "val_frames": data.frames(data.val_episodes),
            # Every labelled frame of every episode used (validation too) cost one expert query.
            "expert_labels": data.frames(used),
            "seeds": [int(s) for s in seeds[seeds >= 0]],
        },
        "train": config.to_json(),
        **({"dagger": algo_record} if algo_record else {}),
        "versions": {"torch": torch.__version__, "numpy": np.__version__},
    }


@dataclass
class Setup:
    data: Dataset
    obs_spec: ObsSpec
    obs_norm: MinMaxNormalizer
    action_norm: MinMaxNormalizer
    relative: RelativeActions | None
    spec: PolicySpec


def setup(config: TrainConfig, store: EpisodeStore, among: np.ndarray | None = None,
          split: tuple[np.ndarray, np.ndarray] | None = None) -> Setup:
    """Steps 1-2: observation spec, split (drawn from ``among``, or given), relative actions,
    normalisers (fitted on the training frames), normalised observations."""
    obs_spec = ObsSpec.from_features(store.meta.features, config.obs_keys or None, str(store.path))
    relative = default_relative(store.meta) if config.relative_actions else None
    train_eps, val_eps = split if split is not None else split_episodes(store, config, among)
    raw = load_raw(store, obs_spec, relative)
    frames = frame_indices(raw.ends, train_eps)
    if raw.labelled is not None:
        frames = frames[raw.labelled[frames]]
    if len(frames) == 0:
        raise DemoError(store.path, "has no labelled training frames")
    obs_norm = MinMaxNormalizer.fit(raw.obs[frames])
    data = raw.dataset(obs_norm, None, train_eps, val_eps)
    data.action_norm = fit_action_normalizer(data, train_eps, config.n_obs, config.chunk)
    spec = PolicySpec(obs_spec.dim, store.meta.action.dim, config.n_obs, config.chunk)
    return Setup(data, obs_spec, obs_norm, data.action_norm, relative, spec)


def train(config: TrainConfig, *, progress: bool = True, resume: bool = False, overwrite: bool = False,
          command: str | None = None, stop_at: int | None = None) -> dict[str, Any]:
    """Train a policy on ``config.data`` into the run directory ``config.out``; returns the summary.

    Ctrl-C saves a checkpoint before stopping; ``stop_at`` stops (and saves) at that step as if
    interrupted, for time-boxed jobs. Either way ``resume=True`` continues bit-exactly.
    """
    config.check()
    policy_config(config.algo, config.policy)  # unknown algo or option: fail before touching anything
    out = Path(config.out)
    if config.threads > 0:
        torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng([config.seed, 0xB0C])

    # ---- 1-2. data and normalisers
    store = EpisodeStore.open(config.data)
    try:
        s = setup(config, store)
    finally:
        store.close()
    data = s.data
    execution = execution_config(config, store.meta.action)
    policy = build_policy(config.algo, s.spec, policy_config(config.algo, config.policy))
    run = run_record(config, store, s, policy, execution, command)
    prepare_run_dir(out, resume, overwrite)

    # ---- 3-4. windows and optimisation
    source = BatchSource(data, data.train_episodes, config.n_obs, config.chunk)
    val_batch = BatchSource(data, data.val_episodes, config.n_obs, config.chunk).fixed(4096, config.seed)
    learner = make_learner(policy, config)
    metrics: dict[str, Any] = {"train_loss": [], "val_loss": [], "eval": []}
    if resume:
        check_resumable(out, run)
        metrics = restore(learner, ckpt.load_train_state(out), rng, out)
        learner.phase_steps = config.steps  # a longer --steps stretches the remaining schedule
        run["created"] = ckpt.read_run(out).get("created", run["created"])
        run["resumed"] = [*ckpt.read_run(out).get("resumed", []), {"at_step": learner.step, "command": command, "time": ckpt.now()}]
    ckpt.write_run(out, run)

    # ---- 5-6. loop, monitoring, checkpoints
    monitor = Monitor(config.eval_episodes, config.seed) if (config.eval_every or config.eval_final) else None
    title = f"{config.algo} on {Path(config.data).name}"
    start = time.perf_counter()

    def evaluate_now() -> None:
        result = monitor(bundle_of(learner, s, store.meta.action, execution, run, out))
        metrics["eval"].append({"step": learner.step, **{k: result[k] for k in ("success_rate", "ci95", "episodes", "mean_length")}})
        bar.update(learner.step, success=f"{result['successes']}/{result['episodes']}")
        save(out, learner, s.obs_norm, s.action_norm, rng, metrics, title=title)

    until = config.steps if stop_at is None else min(stop_at, config.steps)
    try:
        with TrainProgress(config.steps, f"train {config.algo}", progress, learner.step) as bar:
            fit(learner, source, until, rng, metrics, val_batch, bar, evaluate_now if monitor else None)
            if until == config.steps and monitor and not any(e["step"] == learner.step for e in metrics["eval"]):
                evaluate_now()
    except KeyboardInterrupt:
        save(out, learner, s.obs_norm, s.action_norm, rng, metrics, title=title)
        raise
    finally:
        if monitor:
            monitor.close()
    seconds = time.perf_counter() - start
    metrics["final"] = {
        "step": learner.step,
        "train_loss": metrics["train_loss"][-1][1] if metrics["train_loss"] else None,
        "val_loss": metrics["val_loss"][-1][1] if metrics["val_loss"] else None,
        "success_rate": metrics["eval"][-1]["success_rate"] if metrics["eval"] else None,
        "seconds": seconds,
        "expert_labels": run["data"]["expert_labels"],
    }
    save(out, learner, s.obs_norm, s.action_norm, rng, metrics, title=title)
    return {"out": str(out), "algo": config.algo, **metrics["final"], "train_episodes": len(data.train_episodes),
            "val_episodes": len(data.val_episodes), "train_frames": run["data"]["train_frames"]}
