"""One-step diffusion by distillation: ``demo train STORE --algo diffusion --distil TEACHER --out RUN``.

Method: knowledge distillation of the deterministic sampler (Luhman & Luhman 2021, "Knowledge
distillation in iterative generative models for improved sampling speed", arXiv:2101.02388). With
DDIM (eta = 0) the teacher's chunk is a deterministic function ``x0 = F(obs, x_T)`` of the
observation and the start noise. The student, the teacher's own denoiser initialised from its
(EMA) weights and queried once at the top timestep ``T-1`` (:meth:`DiffusionPolicy.one_step`),
regresses that map:

    L = E || student(obs, x_T) - F_teacher,DDIM-k(obs, x_T) ||^2,   x_T ~ N(0, I), obs ~ training windows

Why this method: keeping the teacher's modes (``avoid``: both sides of the obstacle) is the point,
and here it comes from the targets themselves. Each noise has one target, a teacher sample on one
mode, and the noises that lead to different modes lie in different regions of noise space, so the
regression has nothing to average except across the thin boundary between those regions. Consistency
distillation (Song et al. 2023; Consistency Policy, Prasad et al. 2024) learns the same map through
a self-consistency loss between neighbouring points of the teacher's ODE trajectories, with an EMA
target network, a boundary-condition parametrisation and a timestep discretisation to tune; what it
buys (one teacher step per pair instead of k, and optional multi-step refinement) matters for images
on a GPU, not for a 16 x 8 chunk with an 8-step teacher. Both ask one call to do what the teacher
does in k.

Pairs are generated on the fly (Luhman & Luhman pre-generate a data set of them): each training
step takes the shared window sampler's observation windows, draws fresh noise and runs the teacher
(eval mode, no gradient, its traced fast path) for its k DDIM steps, so no pair is seen twice and
nothing is stored (a buffer of 100,000 ``avoid`` pairs would take 130 MB). The price is k teacher
forward passes per step besides the student's forward and backward: at batch 256 and k = 8 on one
CPU thread ~0.4 s of CPU per step, about 4x a step of diffusion training (2,000 steps: ~13 CPU
minutes, half the teacher's 16,000-step training).

Everything else is the shared :class:`demo.training.trainer.TrainingRun` (run directory, record,
resume, checkpoints, metrics, progress), with two differences: the loss is :class:`DistillationLoss`
(the learner's ``loss_module``), and the validation loss is the distillation error on the
validation windows with fixed noise (the teacher's targets computed once), not the denoising loss.

The student is saved as an ordinary diffusion run (``algo`` diffusion, ``inference_steps = 1``,
``prediction = "sample"``, the teacher's normalisers) with ``distilled_from`` in ``run.json``, so
``demo eval``, ``demo bench infer --run`` and ``demo bench multimodal`` take it unchanged.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from demo.errors import DemoError
from demo.progress import Progress
from demo.store import EpisodeStore
from demo.policies import checkpoint as ckpt
from demo.training.config import TrainConfig, for_policy
from demo.training.data import Observation, TrainingData, batch_slice, batch_to, prepare
from demo.policies.diffusion import DiffusionPolicy
from demo.training.optim import EMA
from demo.policies.policy import Policy, config_to_json
from demo.training.trainer import TrainingRun
from demo.policies.visuomotor import VisuomotorPolicy

# The optimisation of a student, where the caller says nothing (then diffusion's own defaults, EMA
# 0.995 included). A fine-tune from the teacher's weights: a tenth of diffusion's learning rate, a
# short warm-up. avoid (200 demos), from the 16,000-step DDIM-8 teacher at 94/100: 89/100 after 200
# steps, 92/100 after 2000 (distillation error on held-out pairs 2.2e-4 -> 0.8e-4); the teacher at
# one step without distillation: 41/100 (its mode average collides).
DISTILL_DEFAULTS: dict[str, Any] = {"steps": 2000, "lr": 1e-4, "warmup_steps": 100, "batch_size": 256}
VALIDATION_WINDOWS = 1024  # the fixed validation pairs (the teacher's k steps on each, once)


# ================================================================================== 1. the teacher
def diffusion_head(policy: Policy) -> DiffusionPolicy | None:
    """The diffusion policy inside ``policy`` (itself, or the head behind image encoders); None if none."""
    head = policy.head if isinstance(policy, VisuomotorPolicy) else policy
    return head if isinstance(head, DiffusionPolicy) else None


def load_teacher(run: str | Path) -> ckpt.PolicyBundle:
    """The teacher's bundle (evaluation weights, eval mode, CPU); refuses a run that is not diffusion."""
    bundle = ckpt.load_bundle(run)
    if diffusion_head(bundle.policy) is None:
        raise DemoError(run, f"is a {bundle.algo!r} run; --distil needs a diffusion teacher (demo train --algo diffusion)")
    return bundle


def student_policy_options(teacher: ckpt.PolicyBundle) -> dict[str, Any]:
    """The student's diffusion config: the teacher's network, sampled in one DDIM step from the top
    timestep, predicting the chunk itself (``one_step``)."""
    head = diffusion_head(teacher.policy)
    assert head is not None
    return config_to_json(dataclasses.replace(head.config, inference_steps=1, sampler="ddim", prediction="sample"))


def student_config(teacher: ckpt.PolicyBundle, **given: Any) -> TrainConfig:
    """The student's resolved :class:`TrainConfig`: what shapes the policy's inputs and outputs from the
    teacher (observation keys, history, chunk, relative actions, encoders, network, execution), the
    optimisation from ``given`` (None = not given), then :data:`DISTILL_DEFAULTS`, then diffusion's.

    A given setting that would make the student another network than the teacher's is refused (one
    DemoError naming the flag). Resolving a resolved config's values again gives the same config.
    """
    rec, spec, obs = teacher.run["policy"], teacher.policy.spec, teacher.obs_spec
    inherited: dict[str, Any] = {
        "n_obs": spec.n_obs,
        "chunk": spec.horizon,
        "obs_keys": (*obs.keys, *obs.images),
        "policy": student_policy_options(teacher),
        "encoder": rec.get("encoder") or {},
    }
    flags = {"n_obs": "--n-obs", "chunk": "--chunk", "obs_keys": "--obs-keys", "policy": "--policy-opt", "encoder": "--encoder"}
    for key, value in inherited.items():
        mine = given.get(key)
        if mine not in (None, {}, ()) and _json(mine) != _json(value):
            raise DemoError(flags[key], f"the student is the teacher's network on the teacher's inputs ({teacher.path}: "
                                        f"{_json(value)}); leave {flags[key]} out")
    relative = teacher.relative is not None
    if given.get("relative_actions") is False and relative:
        raise DemoError("--absolute-actions", f"the teacher {teacher.path} predicts relative actions; the student must too")
    execution = teacher.execution
    loop = {**DISTILL_DEFAULTS, **{k: v for k, v in given.items() if v is not None and k not in inherited}}
    loop.setdefault("execute", execution.execute)
    loop.setdefault("ensemble", execution.ensemble is not None)
    if execution.ensemble is not None:
        loop.setdefault("ensemble_decay", execution.ensemble)
    loop.setdefault("binary_gripper", bool(execution.binary))
    return for_policy("diffusion", **{**loop, **inherited, "relative_actions": relative})


def _json(value: Any) -> Any:
    """Tuples as lists, for comparing a config value with its JSON record."""
    if isinstance(value, dict):
        return {k: _json(v) for k, v in value.items()}
    return [_json(v) for v in value] if isinstance(value, (tuple, list)) else value


def teacher_record(teacher: ckpt.PolicyBundle) -> dict[str, Any]:
    """``run.json["distilled_from"]``: which run, which of its samplers the student learnt, which weights."""
    head = diffusion_head(teacher.policy)
    assert head is not None and teacher.path is not None
    weights = teacher.path / ckpt.POLICY_FILE
    return {
        "run": str(teacher.path.resolve()),
        "method": "knowledge distillation of the DDIM sampler (Luhman & Luhman 2021)",
        "sampler": "ddim",
        "inference_steps": head.config.inference_steps,
        "spacing": head.config.spacing,
        "created": teacher.run.get("created"),
        "policy_sha256": hashlib.sha256(weights.read_bytes()).hexdigest(),
    }


# ================================================================================== 2. the data
def student_data(config: TrainConfig, store: EpisodeStore, teacher: ckpt.PolicyBundle) -> TrainingData:
    """The store's windows as the teacher sees them: its observation keys and its normalisers (the
    student's output is the teacher's, in the teacher's normalised action space). The split is drawn
    as for any run: with the teacher's seed and split settings, its validation episodes."""
    meta, where = store.meta, str(store.path)
    teacher.obs_spec.check_against(meta.features, where)
    if meta.action.to_json() != teacher.action.to_json():
        raise DemoError(where, f"holds {meta.action.name} actions ({meta.action.dim} values); the teacher {teacher.path} "
                               f"outputs {teacher.action.name} ({teacher.action.dim})")
    task, theirs = meta.task or {}, teacher.task
    if (task.get("name"), task.get("options") or {}) != (theirs.get("name"), theirs.get("options") or {}):
        raise DemoError(where, f"holds task {task.get('name')!r} {task.get('options') or ''}; the teacher {teacher.path} "
                               f"was trained on {theirs.get('name')!r} {theirs.get('options') or ''}")
    data = prepare(config, store)
    if data.obs_spec.to_json() != teacher.obs_spec.to_json():
        raise DemoError(where, f"observations {list(data.obs_spec.keys)} differ from the teacher's {list(teacher.obs_spec.keys)}")
    if (data.relative and data.relative.to_json()) != (teacher.relative and teacher.relative.to_json()):
        raise DemoError(where, f"its relative-action dims differ from the teacher's ({teacher.path})")
    with_teacher_norms = dataclasses.replace(data, obs_norm=teacher.obs_norm, action_norm=teacher.action_norm)
    return with_teacher_norms.reload(store, data.train_episodes, data.val_episodes)


# ================================================================================== 3. the loss
class DistillationLoss(nn.Module):
    """``||student one step from x_T - teacher's DDIM-k sample from x_T||^2`` on fresh noise
    (the torch global RNG, seeded and checkpointed by the run), for a batch of observation windows."""

    def __init__(self, student: Policy, teacher: Policy):
        super().__init__()
        self.student = student
        self.teacher = teacher.eval().requires_grad_(False)

    def forward(self, obs: Observation, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        # The demonstrated chunk only gives the shape: the target is the teacher's.
        x_T = torch.randn(action.shape, device=action.device, dtype=action.dtype)
        return F.mse_loss(student_step(self.student, obs, x_T), teacher_sample(self.teacher, obs, x_T))


def _split(policy: Policy, obs: Observation) -> tuple[DiffusionPolicy, torch.Tensor]:
    """The diffusion head and the observation it sees (encoded images and the vector, or the vector)."""
    head = diffusion_head(policy)
    assert head is not None
    return head, (policy.encode(obs) if isinstance(policy, VisuomotorPolicy) else obs)  # type: ignore[arg-type]


@torch.no_grad()
def teacher_sample(teacher: Policy, obs: Observation, x_T: torch.Tensor) -> torch.Tensor:
    """The teacher's chunk from ``x_T`` with its own DDIM sampler (deterministic)."""
    head, seen = _split(teacher, obs)
    return head.sample(seen, x_T)


def student_step(student: Policy, obs: Observation, x_T: torch.Tensor) -> torch.Tensor:
    """The student's one-step chunk from ``x_T``, with gradients."""
    head, seen = _split(student, obs)
    return head.one_step(seen, x_T)


class Validation:
    """The distillation error of the evaluation weights on fixed pairs: the validation windows
    (up to :data:`VALIDATION_WINDOWS`), noise drawn once from the seed, the teacher's targets."""

    def __init__(self, data: TrainingData, teacher: Policy, seed: int, device: torch.device):
        batch = data.windows(data.val_episodes).fixed(VALIDATION_WINDOWS, seed)
        self.pairs: list[tuple[Observation, torch.Tensor, torch.Tensor]] = []
        if batch is None:
            return
        noise = torch.randn(batch[1].shape, generator=torch.Generator().manual_seed(seed))
        for i in range(0, len(noise), 256):
            obs, _, _ = batch_to(batch_slice(batch, i, i + 256), device)
            x_T = noise[i : i + 256].to(device)
            self.pairs.append((obs, x_T, teacher_sample(teacher, obs, x_T)))

    @torch.no_grad()
    def __call__(self, student: Policy) -> float | None:
        if not self.pairs:
            return None
        total = sum(F.mse_loss(student_step(student, o, x), y, reduction="sum").item() for o, x, y in self.pairs)
        return float(total / sum(y.numel() for _, _, y in self.pairs))


# ================================================================================== 4. training
def train(config: TrainConfig, teacher: str | Path, *, progress: Progress | None = None, resume: bool = False,
          overwrite: bool = False, command: str | None = None, stop_at: int | None = None) -> dict[str, Any]:
    """Distil the diffusion run ``teacher`` into a one-step student on ``config.data``, into the run
    directory ``config.out``; returns the summary (as :func:`demo.imitation.bc.train`, plus the
    distillation error before and after). ``config``'s unset settings are resolved by
    :func:`student_config`; Ctrl-C and ``stop_at`` save a checkpoint that ``resume`` continues."""
    bundle = load_teacher(teacher)
    config = student_config(bundle, **config.given())
    if len(config.stores) > 1:
        raise DemoError("--distil", "distils on one store (the teacher's observation windows)")
    with TrainingRun(config, progress=progress, resume=resume, overwrite=overwrite, command=command,
                     name="diffusion (distil)", title=f"one-step distillation of {Path(teacher).name}") as run:
        if run.group is not None:
            raise DemoError("--nproc", "distillation trains in one process")
        record = teacher_record(bundle)
        if resume and (ckpt.read_run(config.out).get("distilled_from") or {}).get("run") != record["run"]:
            raise DemoError(config.out, f"was not distilled from {record['run']}; cannot resume it with another teacher")
        with EpisodeStore.open(config.data) as store:
            data = student_data(config, store, bundle)
            learner = run.new_learner(data)
            learner.policy.load_state_dict(bundle.policy.state_dict())  # the student starts as the teacher
            if learner.ema is not None:
                learner.ema = EMA(learner.policy, config.ema)
            run.begin(store, data, learner)
        run.record["distilled_from"] = record  # begin wrote run.json without it: the shared record knows no teacher
        ckpt.write_run(run.out, run.record)
        if resume:
            run.restore(learner)
            learner.phase_steps = config.steps
        teacher_policy = bundle.policy.to(learner.device)
        learner.loss_module = DistillationLoss(learner.policy, teacher_policy)
        validate = Validation(data, teacher_policy, config.seed, learner.device)
        # The run's own validation would be the student's denoising loss: it validates nothing here.
        run.attach(learner, dataclasses.replace(data, val_episodes=np.zeros(0, np.int64)))
        if not run.metrics.get("val_loss"):
            _validate(run, validate)  # the teacher's weights at one step: the error distillation starts from
        until = config.steps if stop_at is None else min(stop_at, config.steps)
        while learner.step < until:
            run.fit(min(until, (learner.step // config.val_every + 1) * config.val_every))
            _validate(run, validate)
        run.attach(learner, data)  # the record and the summary count the real validation episodes
        if until == config.steps and not any(e["step"] == learner.step for e in run.metrics["eval"]):
            run.evaluate()
        first = run.metrics["val_loss"][0][1] if run.metrics["val_loss"] else None
        return run.finish(distill_val_start=first, teacher=record["run"], teacher_steps=record["inference_steps"])


def _validate(run: TrainingRun, validate: Validation) -> None:
    learner = run.learner
    assert learner is not None
    value = validate(learner.eval_policy())
    if value is not None and not any(s == learner.step for s, _ in run.metrics.setdefault("val_loss", [])):
        run.metrics["val_loss"].append([learner.step, value])
        run.tick(val=value)

