"""The configuration of a training run, and where its defaults live.

:class:`TrainConfig` holds every hyperparameter of a supervised run (behaviour cloning, diffusion,
and DAgger's learners). The settings a policy is tuned for (``steps``, ``lr``, ``chunk``, ...) are
``None`` until resolved: :func:`for_policy` fills each one from, in order,

1. what the caller gave (a CLI flag, a keyword),
2. the policy's own training defaults (:data:`POLICY_DEFAULTS`: BC's 16-step chunks with temporal
   ensembling, diffusion's chunk 16, n_obs 2, execute 4, 16,000 steps), the configuration measured
   best, each with the measurement behind it,
3. :data:`LOOP_DEFAULTS`, the generic ones.

They are plain data here (no torch import), so ``demo train --help`` shows them.

Every caller gets the same run for the same request: the CLI, quickstart, the benchmarks, the
experiments and a Python user who writes ``TrainConfig(data=..., out=..., algo="diffusion")``, since
the trainer resolves a config before it trains (:meth:`TrainConfig.resolved`). The run directory
records the resolved values.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field
from typing import Any

from demo.errors import DemoError
from demo.policies.observation import ObsSpec
from demo.store import EpisodeStore

# The generic training-loop settings, where the policy says nothing.
LOOP_DEFAULTS: dict[str, Any] = {
    "steps": 5000,
    "batch_size": 256,
    "lr": 1e-3,
    "weight_decay": 1e-4,
    "warmup_steps": 500,
    "ema": 0.0,
    "n_obs": 1,
    "chunk": 1,
    "execute": 1,
    "ensemble": False,
    "candidates": 1,
}

# Each policy's measured-best settings (held-out eval seeds, >= 100 episodes; README, Results).
POLICY_DEFAULTS: dict[str, dict[str, Any]] = {
    # pick, 100 scripted demos: 16-step chunks executed with temporal ensembling 99/100, single-step
    # 52-61/100. Chunks are the cure for compounding errors.
    # The same chunks and ensembling serve every --head (demo.policies.heads): executed open-loop, any
    # regressed chunk drifts on avoid (MSE, 8 per query: 0/100; GMM, 2 or 4 per query: 0/100).
    "bc": {"chunk": 16, "ensemble": True},
    # Diffusion Policy's horizon 16 / n_obs 2 and AdamW with warm-up + cosine, with a learning rate and
    # EMA for runs of ~10^4 steps on a CPU (published: 1e-4 and EMA to 0.9999 over ~10^6 steps).
    "diffusion": {
        "chunk": 16,  # horizon
        "n_obs": 2,
        # avoid (200 paired demos, 16000 steps), whose demonstrations pass the obstacle 2 cm away:
        # execute 4 gives 94%/93% (training seeds 0/1), execute 8 91%/93%; pick (100 demos): 96% with 8
        "execute": 4,
        # never temporal ensembling: averaging overlapping chunks that went to different modes is the
        # very mode averaging diffusion is there to avoid
        "ensemble": False,
        "lr": 1e-3,
        "weight_decay": 1e-6,
        "warmup_steps": 500,
        "ema": 0.995,
        "batch_size": 256,
        # ~24 min of one CPU core. avoid (200 demos) reached 80-90% over 4 seeds at 8000 steps and
        # 93-94% at 16000; with 100 demos at 8000 steps 83%. pick: 90% at 6000 steps, 96% at 8000.
        "steps": 16000,
    },
    # flow matching (demo.policies.flow) trains as diffusion does: the same chunks, execution and schedule
    "flow": {"chunk": 16, "n_obs": 2, "execute": 4, "ensemble": False, "lr": 1e-3, "weight_decay": 1e-6,
             "warmup_steps": 500, "ema": 0.995, "batch_size": 256, "steps": 16000},
    # ACT (demo.policies.act): a query every step, temporal ensembling exp(-0.01 i) over every chunk
    # covering the step (ACT's own execution; --ensemble-decay is its k).
    "act": {
        "chunk": 16,
        "execute": 1,
        "ensemble": True,
        # a transformer step costs ~100x an MLP's on a CPU: small batches (the paper: 8), more steps
        "batch_size": 64,
        # pick (100 demos): lr 3e-4 for 3000 steps 63/100; 1e-3 (pre-norm layers) 89 at 5000 steps,
        # 97 at 10000 (17 min of one core on a shared machine). avoid (200 paired demos, seed 0): 85 and 83
        # at 10000 in two runs, 93 at 20000 (33 min); 20000 becomes the default once pick is measured there
        "lr": 1e-3,
        "steps": 10000,
    },
    # the token transformer (demo.policies.transformer): ACT's execution and training settings, its decoder
    "transformer": {"chunk": 16, "execute": 1, "ensemble": True, "batch_size": 64, "lr": 1e-3, "steps": 10000},
}

# BC's sampling heads over BC's settings. GMM (winner-takes-all, the committed draw) on avoid (200
# paired demos, 100 episodes per run, training seeds 0-2): 56, 45, 54/100 at BC's 5,000 steps; 85, 83,
# 81 at 15,000; 90, 84, 87 at 30,000 (about 5 min of one core). Success rises while the validation
# loss does not (seed 0: -3.20 at 15,000, -3.04 at 30,000): the demonstrations pass 2 cm from the
# obstacle, and the longer fit keeps the component means that close. (Before winner-takes-all, with
# the likelihood objective and a fresh draw per query: seed 0 43 / 81 / 14 at 5,000 / 15,000 / 30,000
# steps, seeds 1-2 6 and 15 at 15,000.) Coherent sampling of 16 draws at 30,000 steps: 91 against 90
# (seed 0), no default.
HEAD_DEFAULTS: dict[str, dict[str, Any]] = {"gmm": {"steps": 30000}}

# With camera images (demo.policies.visuomotor) a batch costs ~1000x a state batch on a CPU: smaller
# batches; the rest as measured on pick from front + wrist images (README, Results).
IMAGE_DEFAULTS: dict[str, dict[str, Any]] = {
    "bc": {"batch_size": 64, "steps": 6000},
    "diffusion": {"batch_size": 64, "steps": 6000, "n_obs": 1},
    "flow": {"batch_size": 64, "steps": 6000, "n_obs": 1},
}

# DAgger's learner is BC's policy with BC's own defaults (16-step chunks, ensembled), trained on the expert's
# chunk labels (demo.imitation.dagger). pick, 10 demos + 5 rounds x 10 rollouts, 100 held-out episodes: the
# single-step learner 0/100 (8,484 labels), chunked 46/100 (7,433); HG-DAgger chunked 96/100 and 100/100
# (2,322 and 2,311 labels, seeds 0/1) against BC's 96/100 and 97/100 from 50 demos (2,434 labels).
DAGGER_DEFAULTS: dict[str, Any] = {}


def setting(default: Any = None, help: str = "", *, flag: str | None = None, metavar: str | None = None,
            unset: str | None = None, resume: bool = True, default_factory: Any = None) -> Any:
    """A configuration field and its command-line option in one place.

    ``help`` (and ``flag``, default ``--field-name``; ``metavar``; ``unset``: what ``None`` means, shown
    as the default) make it an option of the command that fills this config (``demo train`` builds its
    options from these, :mod:`demo.cli.config_options`); a field without ``help`` is set another way
    (the command says how). ``resume=False``: ``--resume`` may change it (it does not shape the
    training so far: the step count, execution, monitoring, where it runs)."""
    metadata = {"resume": resume}
    if help:
        metadata.update(help=help, flag=flag, metavar=metavar, unset=unset)
    if default_factory is not None:
        return field(default_factory=default_factory, metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass
class TrainConfig:
    """Every hyperparameter of a training run. ``None`` = the policy's default (see :func:`for_policy`)."""

    # ---- what and where (set by demo train's arguments: STORE..., --out, --algo, --policy-opt/--head, --encoder/--crop)
    data: str | tuple[str, ...] = ""  # episode store, or several trained on as one (demo.training.data.prepare_union)
    # Per store of a union, the share of each batch drawn from it (sums to 1; set by --mix STORE=W); () = in
    # proportion to the stores' windows
    mix: tuple[float, ...] = ()
    out: str = ""  # run directory
    algo: str = "bc"  # registered policy (demo.policies.policy): bc (MLP), diffusion, ...
    policy: dict[str, Any] = field(default_factory=dict)  # the policy's Config fields, e.g. {"hidden": (256, 256)}
    # Image encoders, for stores with cameras (demo.policies.encoders.EncoderConfig fields, e.g. {"backbone": "resnet18"})
    encoder: dict[str, Any] = field(default_factory=dict)
    # The instruction encoder (demo.policies.instruction.TextConfig fields, e.g. {"dim": 128}; set by --text-opt)
    text: dict[str, Any] = field(default_factory=dict)
    seed: int = setting(0, "Seed of initialisation, batches, split and rollouts.")
    # ---- tuned per policy (None until resolved; the defaults shown are POLICY_DEFAULTS')
    steps: int | None = setting(None, "Optimiser steps (DAgger: round 0).", resume=False)
    # windows per batch, per process when data-parallel (global: N x this; lr unchanged)
    batch_size: int | None = setting(None, "Windows per batch.")
    lr: float | None = setting(None, "Peak learning rate (AdamW, warm-up then cosine).")
    weight_decay: float | None = setting(None, "AdamW weight decay, not on biases.")
    warmup_steps: int | None = setting(None, "Warm-up steps.", flag="--warmup")
    ema: float | None = setting(None, "EMA decay of the weights used for evaluation; 0 = off.")
    n_obs: int | None = setting(None, "Observation history in frames.")
    chunk: int | None = setting(None, "Actions predicted per query (action chunking when > 1).")
    execute: int | None = setting(None, "Actions executed per query (receding horizon).", resume=False)
    ensemble: bool | None = setting(None, "Temporal ensembling of overlapping chunks (ACT).", resume=False)
    candidates: int | None = setting(None, "Chunks a sampling policy draws per query at execution, the one most coherent "
                                           "with the chunk before kept (1 = off; demo.policies.actor).", resume=False)
    # A policy served to a robot that executes asynchronously (demo serve): told up to this many committed actions at
    # the start of its chunk, so that a late answer continues what the robot already does (demo.policies.prefix)
    prefix_steps: int = setting(0, "Train the policy to continue up to this many committed actions at the start of "
                                   "its chunk, for asynchronous execution under inference delay (demo serve; "
                                   "0 = off; less than --chunk).")
    # A policy from cameras: a state it is not given (comma-separated store keys, e.g. obs.object_pos) that its
    # encoders learn to predict as well (demo.policies.visuomotor); the loss's weight is the encoder's aux_weight
    aux_target: str | None = setting(None, "Train the camera encoders to predict these low-dim store keys as well "
                                           "(comma-separated, e.g. obs.object_pos; an auxiliary loss, not an input).",
                                     metavar="KEYS", unset="none")
    # ---- the same for every policy
    ensemble_decay: float = setting(0.01, "Ensembling weight exp(-m i) by a prediction's age i (ACT: 0.01).", resume=False)
    min_lr_ratio: float = setting(0.01, "The cosine schedule decays to this fraction of --lr.")
    grad_clip: float = setting(10.0, "Max gradient norm; 0 = off.", resume=False)
    binary_gripper: bool = setting(False, "Execute the action's gripper entry as open/closed (>= 0.5: closed).",
                                   resume=False)
    # default: low-dim obs.* keys except velocities (demo.policies.observation); ("all",) = all; set by --obs-keys
    obs_keys: tuple[str, ...] = ()
    instructions: bool | None = setting(None, "Condition the policy on each episode's instruction (the stores' "
                                              "instruction column; demo.policies.instruction).",
                                        unset="when the training episodes hold more than one")
    obs_noise: float = setting(0.0, "Std of Gaussian noise on normalised observations during training.")
    # predict joint targets relative to the current joint positions (demo.policies.relative); --absolute-actions: False
    relative_actions: bool = True
    train_mask: str | None = setting(None, "Train on this store mask's episodes only (e.g. a curated subset).",
                                     metavar="NAME", unset="every episode")
    val_mask: str | None = setting(None, "Validation episodes = this store mask's episodes.", metavar="NAME",
                                   unset="--val-fraction")
    val_fraction: float = setting(0.1, "Otherwise: this fraction of episodes, drawn with the seed.")
    include_failures: bool = setting(False, "Also train on episodes that did not succeed.")
    log_every: int = setting(100, "Steps between logged training losses.", resume=False)
    val_every: int = setting(500, "Steps between validation losses.", resume=False)
    # ---- monitoring rollouts (demo train: --eval-every, --eval-episodes; 0 episodes = none)
    eval_every: int = setting(0, resume=False)  # rollout evaluation every N steps; 0 = only if eval_final
    eval_episodes: int = setting(10, resume=False)
    eval_final: bool = setting(False, resume=False)  # evaluate once more at the end
    # ---- where it runs (set by --robot, --device: options shared with other commands)
    robot: str | None = setting(None, resume=False)  # robot config TOML, where the store's recorded robot files cannot be found
    device: str = setting("auto", resume=False)  # auto (CUDA, else MPS, else CPU) | cpu | cuda | mps (demo.policies.device)
    # A kill loses at most this much training; each save costs milliseconds for these networks (the cost is in
    # metrics.json: checkpoint_seconds).
    checkpoint_every: float = setting(60.0, "Seconds between train-state saves (a kill loses at most this much; "
                                            "0 = only at evaluations and the end).", resume=False)
    # small networks gain little from more threads, and idle ones busy-wait on a shared machine
    threads: int = setting(1, "Torch threads (0 = torch's default).", resume=False)

    @property
    def stores(self) -> tuple[str, ...]:
        """The episode stores trained on, in order (one unless a union)."""
        return (self.data,) if isinstance(self.data, str) else tuple(self.data)

    def given(self) -> dict[str, Any]:
        """The fields that are set (not ``None``)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) is not None}

    def resolved(self) -> "TrainConfig":
        """This config with every ``None`` setting filled by the policy's defaults, then the generic ones."""
        return for_policy(self.algo, **self.given())

    def check(self) -> None:
        """Raise a :class:`DemoError` naming the flag of the first invalid value (resolved configs only)."""
        unresolved = [f.name for f in dataclasses.fields(self) if f.name in LOOP_DEFAULTS and getattr(self, f.name) is None]
        if unresolved:
            raise ValueError(f"TrainConfig is not resolved ({', '.join(unresolved)}); call .resolved() first")
        positive = {"steps": self.steps, "batch_size": self.batch_size, "n_obs": self.n_obs, "chunk": self.chunk,
                    "execute": self.execute, "candidates": self.candidates, "log_every": self.log_every,
                    "val_every": self.val_every}
        for name, value in positive.items():
            if value < 1:
                raise DemoError(f"--{name.replace('_', '-')}", f"must be at least 1, got {value}")
        if self.execute > self.chunk:
            raise DemoError("--execute", f"cannot exceed --chunk ({self.chunk}), got {self.execute}")
        if self.prefix_steps and not 0 < self.prefix_steps < self.chunk:
            raise DemoError("--prefix-steps", f"must lie in [0, --chunk={self.chunk}), got {self.prefix_steps}")
        if not 0 <= self.val_fraction < 1:
            raise DemoError("--val-fraction", f"must lie in [0, 1), got {self.val_fraction}")
        if not 0 <= self.ema < 1:
            raise DemoError("--ema", f"must lie in [0, 1), got {self.ema}")
        if self.lr <= 0:
            raise DemoError("--lr", f"must be > 0, got {self.lr}")
        if self.ensemble_decay < 0:
            raise DemoError("--ensemble-decay", f"must be >= 0, got {self.ensemble_decay}")
        if self.mix:
            if len(self.mix) != len(self.stores):
                raise DemoError("--mix", f"gives {len(self.mix)} weights for {len(self.stores)} stores")
            if min(self.mix) < 0 or abs(sum(self.mix) - 1.0) > 1e-6:
                raise DemoError("--mix", f"weights must be >= 0 and sum to 1, got {', '.join(f'{w:g}' for w in self.mix)} "
                                         f"(sum {sum(self.mix):g})")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["obs_keys"] = list(self.obs_keys)
        d["mix"] = list(self.mix)
        if not self.mix:  # recorded only when set: runs without it read as before
            d.pop("mix")
        if not isinstance(self.data, str):
            d["data"] = list(self.data)
        d["policy"] = {k: list(v) if isinstance(v, tuple) else v for k, v in self.policy.items()}
        for key in ("encoder", "text"):
            if not d[key]:  # recorded only when set: runs without it read as before
                d.pop(key)
        return d


def policy_defaults(name: str, images: bool = False, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """The training-loop settings policy ``name`` is trained with unless told otherwise (``images``:
    on camera images; ``options``: the policy's options, BC's ``head`` choosing :data:`HEAD_DEFAULTS`)."""
    head = HEAD_DEFAULTS.get(str((options or {}).get("head")), {}) if name == "bc" else {}
    return {**LOOP_DEFAULTS, **POLICY_DEFAULTS.get(name, {}), **head, **(IMAGE_DEFAULTS.get(name, {}) if images else {})}


def reads_images(data: str | tuple[str, ...] | None, obs_keys: tuple[str, ...] = ()) -> bool:
    """Whether a policy trained on the store ``data`` (several: the first) with ``obs_keys`` reads camera images.

    False where the store cannot be read: the data pipeline then says what is wrong with it."""
    if data and not isinstance(data, str):
        data = data[0]
    if not data:
        return False
    try:
        with EpisodeStore.open(data) as store:
            return bool(ObsSpec.from_features(store.meta.features, obs_keys or None).images)
    except (DemoError, OSError, ValueError, KeyError, TypeError):
        return False


def for_policy(name: str, **given: Any) -> TrainConfig:
    """A resolved :class:`TrainConfig` for policy ``name``: ``given`` values (``None`` = not given) win,
    then the policy's defaults (:data:`IMAGE_DEFAULTS` when the data has cameras the policy reads, over
    BC's :data:`HEAD_DEFAULTS`, over :data:`POLICY_DEFAULTS`), then :data:`LOOP_DEFAULTS`."""
    from demo.policies.policy import policy_class  # deferred: torch stays out of demo --help

    policy_class(name)  # an unknown policy fails here, naming the known ones
    given = {k: v for k, v in given.items() if v is not None}
    given.pop("algo", None)
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(given) - known)
    if unknown:
        raise TypeError(f"TrainConfig has no field {', '.join(unknown)}")
    # Only a setting still missing needs the store's cameras: a resolved config (the trainer resolves
    # again what the CLI resolved) opens nothing.
    image_tuned = {k for table in IMAGE_DEFAULTS.values() for k in table}
    images = not image_tuned <= set(given) and reads_images(given.get("data"), tuple(given.get("obs_keys") or ()))
    values = {**policy_defaults(name, images, given.get("policy")), **given, "algo": name}
    if "execute" not in given:  # a shorter --chunk than the policy's default shortens what is executed too
        values["execute"] = min(values["execute"], values["chunk"])
    return TrainConfig(**values)


# What --resume may not change: the data (checked by path), the policy and everything that shapes its training.
RESUME_KEYS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(TrainConfig)
                                     if f.metadata.get("resume", True) and f.name not in ("data", "out"))
