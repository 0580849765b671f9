"""`demo train`: imitation from a store (every algorithm :mod:`demo.algorithms` lists for it) into a run directory.

The command fills the algorithm's configuration (:class:`TrainConfig`, or :class:`DaggerConfig` for
the DAgger family) from the flags and hands it to :func:`demo.algorithms.train`; the library resolves
the defaults and validates. Which flag sets which field: :data:`FIELD_FLAGS` (a test holds the two
to each other)."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

import typer

from demo import algorithms
from demo.cli.config_options import config_options, option_fields, with_options
from demo.cli.main import app, invocation
from demo.cli.options import (address_option, device_option, executor_option, json_option, overwrite_option,
                              robot_option)
from demo.cli.output import kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.errors import DemoError
from demo.executor import ExecutorConfig
from demo.imitation.config import DaggerConfig
from demo.training.config import (DAGGER_DEFAULTS, HEAD_DEFAULTS, IMAGE_DEFAULTS, LOOP_DEFAULTS, POLICY_DEFAULTS, TrainConfig,
                                  policy_defaults)

FAMILY = algorithms.family()  # rollouts + aggregation: DaggerConfig
ALGOS = algorithms.names(algorithms.TRAIN)


def _stores_and_weights(stores: list[str], mix: list[str]) -> tuple[list[str], tuple[float, ...]]:
    """The stores to train on (STORE... or --mix's) and their batch shares (--mix's; () without)."""
    if mix and stores:
        raise DemoError("--mix", "names the stores with their weights: give the stores either as STORE... or as --mix")
    if not mix and not stores:
        raise DemoError("STORE", "give the episode store(s) to learn from (or --mix STORE=W ...)")
    weights = []
    for item in mix:
        path, sep, weight = item.rpartition("=")
        try:
            weights.append(float(weight))
        except ValueError:
            raise DemoError("--mix", f"{item!r} is not STORE=WEIGHT (e.g. pick.zarr=0.7)") from None
        if not sep or not path:
            raise DemoError("--mix", f"{item!r} is not STORE=WEIGHT (e.g. pick.zarr=0.7)")
        stores.append(path)
    return stores, tuple(weights)


def parse_policy_opts(items: list[str], flag: str = "--policy-opt") -> dict[str, str]:
    opts = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise DemoError(flag, f"{item!r} is not KEY=VALUE (e.g. hidden=512,512)")
        opts[key.strip()] = value.strip()
    return opts


def _defaults(key: str) -> str | None:
    """A tuned setting's default per algorithm, from the library's tables (demo.training.config); None
    for a setting the policies do not tune."""
    if key not in LOOP_DEFAULTS:
        return None
    values = {name: policy_defaults(name)[key] for name in POLICY_DEFAULTS}
    values["dagger"] = {**policy_defaults("bc"), **DAGGER_DEFAULTS}[key]
    text = str(next(iter(values.values()))) if len(set(map(str, values.values()))) == 1 else \
        ", ".join(f"{name} {value}" for name, value in values.items())
    heads = {head: policy_defaults("bc", options={"head": head})[key] for head in HEAD_DEFAULTS if key in HEAD_DEFAULTS[head]}
    images = {name: policy_defaults(name, images=True)[key] for name in IMAGE_DEFAULTS if key in IMAGE_DEFAULTS[name]}
    return text + "".join(f"; --head {head}: {value}" for head, value in heads.items()) + \
        ("; with images: " + ", ".join(f"{name} {value}" for name, value in images.items()) if images else "")


TRAIN_OPTIONS = {f.name for f in option_fields(TrainConfig)}
DAGGER_OPTIONS = {f.name for f in option_fields(DaggerConfig)}
# Fields demo train sets from its own arguments rather than a generated option (tests/training/test_cli_options.py
# holds this list, the generated options and the dataclasses to each other).
SET_BY_ARGUMENTS = {"data": "STORES", "mix": "--mix", "out": "--out", "algo": "--algo", "policy": "--policy-opt", "encoder": "--encoder", "text": "--text-opt",
                    "obs_keys": "--obs-keys", "relative_actions": "--absolute-actions", "eval_every": "--eval-every",
                    "eval_episodes": "--eval-episodes", "eval_final": "--eval-episodes", "robot": "--robot",
                    "device": "--device", "train": "STORES"}


@app.command()
@with_options("algo", config_options(TrainConfig, _defaults), config_options(DaggerConfig, prefix="dagger family: "))
def train(
    stores: list[str] = typer.Argument(None, metavar="STORE", help="Episode store to learn from (e.g. pick.zarr); never "
                                       "modified. Several: one policy on their union (same action representation, e.g. two "
                                       "arms' ee7 stores; same task unless every episode carries an instruction).",
                                       show_default=False),
    mix: list[str] = typer.Option([], "--mix", metavar="STORE=W", help="A store and its share of each batch (repeatable, "
                                  "instead of STORE...; the weights sum to 1).", show_default="batches in proportion to "
                                  "the stores' windows"),
    out: Path = typer.Option(..., "--out", "-o", metavar="RUN", help="Run directory to write (checkpoints, metrics, curves).",
                             show_default=False),
    algo: str = typer.Option("bc", help=f"Algorithm: {', '.join(ALGOS)}."),
    obs_keys: str = typer.Option(None, help="Comma-separated obs.* keys; shorthands: all (every low-dim key), images, proprio.",
                                 show_default="images + proprio with cameras, else low-dim keys except velocities"),
    absolute_actions: bool = typer.Option(False, "--absolute-actions", help="Predict absolute joint targets instead of targets relative to the joint positions."),
    encoder: str = typer.Option(None, metavar="small|resnet18", help="Image encoder per camera (stores with cameras): small (CPU) or a GroupNorm ResNet-18 (GPU).",
                                show_default="small"),
    crop: float = typer.Option(None, help="Random-crop side as a fraction of the image (centre crop at evaluation); 1 = off.",
                               show_default="0.875"),
    color_jitter: float = typer.Option(None, "--color-jitter", metavar="J", help="Colour jitter of camera images in "
                                       "training: brightness +-J, contrast and saturation x 1+-J (0 = off).",
                                       show_default="0"),
    aux_weight: float = typer.Option(None, "--aux-weight", metavar="W", help="Weight of the --aux-target loss beside "
                                     "the action loss.", show_default="1"),
    device: str = device_option(),
    head: str = typer.Option(None, metavar="mse|gmm|discrete", help="bc, dagger: output head (= --policy-opt head=...): "
                             "regression, Gaussian mixture or per-dimension bins over the chunk.", show_default="mse"),
    policy_opt: list[str] = typer.Option([], "--policy-opt", metavar="KEY=VALUE", help="Policy option (repeatable), e.g. hidden=512,512.",
                                         show_default="none"),
    text_opt: list[str] = typer.Option([], "--text-opt", metavar="KEY=VALUE", help="Instruction encoder option "
                                       "(repeatable): dim, layers, heads, dropout, film (BC's MLP: FiLM, else appended), film_image_head "
                                       "(from cameras: FiLM BC's MLP as on state, default false), film_images "
                                       "(from cameras: FiLM the image encoders too); init=RUN "
                                       "starts from an earlier instruction-conditioned run's tokenizer and encoder, "
                                       "freeze=true keeps it as it is.", show_default="none"),
    eval_every: int = typer.Option(0, help="Roll the policy out every N steps (0 = only at the end with --eval-episodes > 0)."),
    eval_episodes: int = typer.Option(0, help="Episodes per rollout evaluation during training (0 = none)."),
    robot: Path = robot_option("Robot config TOML, where the store's recorded robot files cannot be found.", "the store's"),
    algo_opt: list[str] = typer.Option([], "--algo-opt", metavar="KEY=VALUE", help="safedagger (hidden, steps), aggrevate "
                                       "(states, candidates, sigma, failure_cost), dart (alpha), perturb (sigma, tries): "
                                       "the algorithm's own option (repeatable).", show_default="none"),
    workers: int = typer.Option(1, help="dagger: rollout processes, or Ray actors (the episodes do not depend on it).",
                                show_default="1: in this process"),
    executor: str = executor_option(),
    address: str = address_option(),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its last checkpoint."),
    overwrite: bool = overwrite_option("an existing run in --out"),
    json_out: str = json_option("the run summary"),
    nproc: int = typer.Option(1, "--nproc", help="Data-parallel processes (torchrun, DDP; --batch-size is per process).",
                              show_default="1: this process alone"),
    distil: Path = typer.Option(None, "--distil", metavar="RUN", help="diffusion: distil this diffusion run into a one-step "
                                "student on STORE (knowledge distillation of its DDIM sampler).", show_default="no teacher"),
    **settings: Any,  # one per option field of TrainConfig and DaggerConfig (with_options, below)
) -> None:
    """Train a policy on a store: bc (MLP, action chunks, --head), dagger and its family (safedagger, aggrevate, dart,
    perturb: with the task's expert), diffusion, flow (flow matching), act (ACT)."""
    from demo.training import distributed  # deferred: torch stays out of demo --help

    algorithms.algorithm(algo, algorithms.TRAIN)  # an unknown --algo fails here, naming the choices
    stores, weights = _stores_and_weights(stores or [], mix)
    if algo in FAMILY and len(stores) > 1:
        raise DemoError("--algo", f"{algo} trains on one store (it rolls out on one robot and aggregates into one store)")
    if algo not in FAMILY and (workers != 1 or executor != "process" or address):
        raise DemoError("--workers", "--workers, --executor and --address run DAgger's rollouts: use them with --algo dagger")
    algorithms.check_options(algo, parse_policy_opts(algo_opt, "--algo-opt"))
    if nproc < 1:
        raise DemoError("--nproc", f"must be at least 1, got {nproc}")
    if distil is not None and (algo != "diffusion" or max(nproc, distributed.env_world_size()) > 1):
        raise DemoError("--distil", "distils a diffusion run into a diffusion student in one process: use --algo diffusion, "
                                    "without --nproc")
    if algo in FAMILY and max(nproc, distributed.env_world_size()) > 1:
        raise DemoError("--nproc", f"{algo} trains in one process (its rollouts and store are not data-parallel)")
    if nproc > 1 and distributed.env_world_size() == 1:  # not yet under torchrun: become its N processes
        from demo.training.run import check_run_directory  # deferred: torch stays out of demo --help

        check_run_directory(out, resume, overwrite)  # refused here in one line, not once per process
        raise typer.Exit(distributed.launch(_without_nproc(shlex.split(invocation())[1:]), nproc))
    learner = {k: v for k, v in settings.items() if k in TRAIN_OPTIONS}
    given = dict(
        learner,
        data=str(stores[0]) if len(stores) == 1 else tuple(str(s) for s in stores),  # several: their union
        mix=weights,
        out=str(out), policy=_with_head(parse_policy_opts(policy_opt), head, algo), obs_keys=_obs_keys(obs_keys),
        relative_actions=not absolute_actions, eval_every=eval_every if eval_episodes else 0,
        eval_episodes=max(1, eval_episodes), eval_final=eval_episodes > 0, robot=str(robot) if robot else None,
        device=device, text=parse_policy_opts(text_opt, "--text-opt"), encoder={k: v for k, v in (("backbone", encoder), ("crop", crop), ("color_jitter", color_jitter), ("aux_weight", aux_weight))
                                if v is not None},
    )
    how = dict(resume=resume, overwrite=overwrite, command=invocation())
    if algo in FAMILY:
        config = DaggerConfig(train=TrainConfig(**given), **{k: v for k, v in settings.items() if k in DAGGER_OPTIONS})
        with bars() as progress:
            summary = algorithms.train(algo, config, options=parse_policy_opts(algo_opt, "--algo-opt"), progress=progress,
                                       executor=ExecutorConfig(executor, workers, address), **how)
    elif distil is not None:
        from demo.imitation.distill import train as train_distil  # deferred: torch stays out of demo --help

        with bars() as progress:  # the student's settings are resolved from the teacher's
            summary = train_distil(TrainConfig(algo=algo, **given), distil, progress=progress, **how)
    else:
        with bars() as progress:
            summary = algorithms.train(algo, TrainConfig(algo=algo, **given), progress=progress, **how)
    rows = [
        ("run", summary["out"]),
        ("algo", algo),
        ("steps", summary["step"]),
        ("train loss", summary["train_loss"]),
        ("validation loss", summary["val_loss"] if summary["val_loss"] is not None else "-"),
        *([("validation loss, images shuffled", f"{summary['val_loss_images_shuffled']:.4g}"
            + ("" if summary["reads_cameras"] else " [yellow](about the same: the policy does not read its cameras)[/]"))]
          if "reads_cameras" in summary else []),
        ("expert labels", summary["expert_labels"]),
        ("rollout success", f"{summary['success_rate']:.0%}" if summary["success_rate"] is not None else "- (see demo eval)"),
        ("seconds", f"{summary['seconds']:.1f}"),
    ]
    if algo in FAMILY:
        for r in summary["rounds"]:
            rows.append((f"round {r['round']}", f"labels {r['labels_total']}, rollout success "
                         f"{'-' if r['rollout_success'] is None else format(r['rollout_success'], '.0%')}"
                         + "".join(f", {k.replace('_', ' ')} {r[k]}" for k in ("takeovers", "sim_steps") if k in r)))
    if distributed.is_main_process():  # one table and one JSON summary per run, not per rank
        report_console(json_out).print(kv_table("trained", rows))
        per_task = summary.get("val_loss_per_instruction") or {}
        if per_task:  # one policy for many tasks: which of them it fits worst
            report_console(json_out).print(table("validation loss per instruction, worst first", ("instruction", "loss"),
                                                 [(text, f"{loss:.4g}") for text, loss in
                                                  sorted(per_task.items(), key=lambda item: -item[1])]))
        write_json(summary, json_out)


def _with_head(opts: dict[str, str], head: str | None, algo: str) -> dict[str, str]:
    """``--head`` as the MLP's ``head`` option (BC's, and DAgger's learner's)."""
    if head is None:
        return opts
    if algo not in ("bc", *FAMILY):
        raise DemoError("--head", f"applies to bc and the dagger family (the MLP), not {algo!r}")
    return {**opts, "head": head}


def _without_nproc(args: list[str]) -> list[str]:
    """The command line without ``--nproc N`` (torchrun's processes are started with the rest)."""
    kept, skip = [], False
    for arg in args:
        if skip:
            skip = False
        elif arg == "--nproc":
            skip = True
        elif not arg.startswith("--nproc="):
            kept.append(arg)
    return kept


def _obs_keys(text: str | None) -> tuple[str, ...]:
    if not text:
        return ()
    if text.strip() == "all":
        return ("all",)
    return tuple(k.strip() for k in text.split(",") if k.strip())
