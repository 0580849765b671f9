"""`demo train`: behaviour cloning, DAgger (and any registered policy) into a run directory;
`demo bench train`: training throughput with the real data pipeline vs bare forward/backward."""

from __future__ import annotations

import shlex
from pathlib import Path

import typer

from demo.cli.main import app, invocation
from demo.cli.options import (address_option, device_option, executor_option, json_option, overwrite_option,
                              robot_option, store_argument)
from demo.cli.output import kv_table, report_console, write_json
from demo.cli.progress import bars
from demo.errors import DemoError

FAMILY = ("dagger", "safedagger", "aggrevate", "dart", "perturb")  # rollouts + aggregation (demo.imitation.dagger.make_family)
ALGOS = ("bc", *FAMILY, "diffusion", "act")


def parse_policy_opts(items: list[str], flag: str = "--policy-opt") -> dict[str, str]:
    opts = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise DemoError(flag, f"{item!r} is not KEY=VALUE (e.g. hidden=512,512)")
        opts[key.strip()] = value.strip()
    return opts


def _defaults(key: str) -> str:
    """A flag's default per algorithm, from the library's table (demo.training.config)."""
    from demo.training.config import DAGGER_DEFAULTS, HEAD_DEFAULTS, IMAGE_DEFAULTS, POLICY_DEFAULTS, policy_defaults

    values = {name: policy_defaults(name)[key] for name in POLICY_DEFAULTS}
    values["dagger"] = {**policy_defaults("bc"), **DAGGER_DEFAULTS}[key]
    text = str(next(iter(values.values()))) if len(set(map(str, values.values()))) == 1 else \
        ", ".join(f"{name} {value}" for name, value in values.items())
    heads = {head: policy_defaults("bc", options={"head": head})[key] for head in HEAD_DEFAULTS if key in HEAD_DEFAULTS[head]}
    images = {name: policy_defaults(name, images=True)[key] for name in IMAGE_DEFAULTS if key in IMAGE_DEFAULTS[name]}
    return text + "".join(f"; --head {head}: {value}" for head, value in heads.items()) + \
        ("; with images: " + ", ".join(f"{name} {value}" for name, value in images.items()) if images else "")


@app.command()
def train(
    stores: list[str] = store_argument("Episode store to learn from (e.g. pick.zarr); never modified. Several: one policy "
                                        "on their union (same task and action representation, e.g. two arms' ee7 stores)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="RUN", help="Run directory to write (checkpoints, metrics, curves).",
                             show_default=False),
    algo: str = typer.Option("bc", help=f"Algorithm: {', '.join(ALGOS)}."),
    steps: int = typer.Option(None, help="Optimiser steps (DAgger: round 0).", show_default=_defaults("steps")),
    seed: int = typer.Option(0, help="Seed of initialisation, batches, split and rollouts."),
    batch_size: int = typer.Option(None, help="Windows per batch.", show_default=_defaults("batch_size")),
    lr: float = typer.Option(None, help="Peak learning rate (AdamW, warm-up then cosine).", show_default=_defaults("lr")),
    weight_decay: float = typer.Option(None, help="AdamW weight decay, not on biases.", show_default=_defaults("weight_decay")),
    warmup: int = typer.Option(None, help="Warm-up steps.", show_default=_defaults("warmup_steps")),
    ema: float = typer.Option(None, help="EMA decay of the weights used for evaluation; 0 = off.", show_default=_defaults("ema")),
    n_obs: int = typer.Option(None, help="Observation history in frames.", show_default=_defaults("n_obs")),
    chunk: int = typer.Option(None, help="Actions predicted per query (action chunking when > 1).", show_default=_defaults("chunk")),
    execute: int = typer.Option(None, help="Actions executed per query (receding horizon).", show_default=_defaults("execute")),
    ensemble: bool = typer.Option(None, "--ensemble/--no-ensemble", help="Temporal ensembling of overlapping chunks (ACT).",
                                  show_default=_defaults("ensemble")),
    ensemble_decay: float = typer.Option(0.01, help="Ensembling weight exp(-m i) by a prediction's age i (ACT: 0.01)."),
    candidates: int = typer.Option(None, help="Chunks a sampling policy draws per query at execution, the one most "
                                   "coherent with the chunk before kept (1 = off).", show_default=_defaults("candidates")),
    obs_keys: str = typer.Option(None, help="Comma-separated obs.* keys; shorthands: all (every low-dim key), images, proprio.",
                                 show_default="images + proprio with cameras, else low-dim keys except velocities"),
    absolute_actions: bool = typer.Option(False, "--absolute-actions", help="Predict absolute joint targets instead of targets relative to the joint positions."),
    obs_noise: float = typer.Option(0.0, help="Std of Gaussian noise on normalised observations during training."),
    encoder: str = typer.Option(None, metavar="small|resnet18", help="Image encoder per camera (stores with cameras): small (CPU) or a GroupNorm ResNet-18 (GPU).",
                                show_default="small"),
    crop: float = typer.Option(None, help="Random-crop side as a fraction of the image (centre crop at evaluation); 1 = off.",
                               show_default="0.875"),
    device: str = device_option(),
    head: str = typer.Option(None, metavar="mse|gmm|discrete", help="bc, dagger: output head (= --policy-opt head=...): "
                             "regression, Gaussian mixture or per-dimension bins over the chunk.", show_default="mse"),
    policy_opt: list[str] = typer.Option([], "--policy-opt", metavar="KEY=VALUE", help="Policy option (repeatable), e.g. hidden=512,512.",
                                         show_default="none"),
    train_mask: str = typer.Option(None, metavar="NAME", help="Train on this store mask's episodes only (e.g. a curated subset).",
                                   show_default="every episode"),
    val_mask: str = typer.Option(None, metavar="NAME", help="Validation episodes = this store mask's episodes.",
                                 show_default="--val-fraction"),
    val_fraction: float = typer.Option(0.1, help="Otherwise: this fraction of episodes, drawn with the seed."),
    include_failures: bool = typer.Option(False, "--include-failures", help="Also train on episodes that did not succeed."),
    eval_every: int = typer.Option(0, help="Roll the policy out every N steps (0 = only at the end with --eval-episodes > 0)."),
    eval_episodes: int = typer.Option(0, help="Episodes per rollout evaluation during training (0 = none)."),
    threads: int = typer.Option(1, help="Torch threads (0 = torch's default)."),
    robot: Path = robot_option("Robot config TOML, where the store's recorded robot files cannot be found.", "the store's"),
    task: str = typer.Option(None, help="dagger: the task to roll out (must be the data's).", show_default="the data's"),
    rounds: int = typer.Option(5, help="dagger: rounds of rollouts + aggregation + retraining."),
    episodes_per_round: int = typer.Option(10, help="dagger: learner rollouts per round."),
    round_steps: int = typer.Option(2000, help="dagger: optimiser steps of the learner trained after each round."),
    warm_start: bool = typer.Option(False, "--warm-start", help="dagger: fine-tune the previous learner instead of training a new one per round."),
    beta: str = typer.Option("indicator", help="dagger: expert-mixing schedule indicator | linear:N | exp:P."),
    gate: str = typer.Option(None, metavar="deviation:THRESH", help="HG-DAgger: the expert takes over and labels only where the learner strays by THRESH rad "
                             "(safedagger: the deviation its classifier predicts).", show_default="plain DAgger"),
    max_labels: int = typer.Option(None, "--max-labels", help="dagger family: stop rolling out once this many expert labels "
                                   "are spent (demonstrations included).", show_default="no limit"),
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
) -> None:
    """Train a policy on a store: bc (MLP, action chunks, --head), dagger and its family (safedagger, aggrevate, dart,
    perturb: with the task's expert), diffusion, act (ACT)."""
    from demo.training import distributed
    from demo.imitation.bc import train as train_bc
    from demo.training.config import for_policy

    if algo not in ALGOS:
        raise DemoError("--algo", f"unknown algorithm {algo!r} (choose from {', '.join(ALGOS)})")
    if algo in FAMILY and len(stores) > 1:
        raise DemoError("--algo", f"{algo} trains on one store (it rolls out on one robot and aggregates into one store)")
    if algo not in FAMILY and (workers != 1 or executor != "process" or address):
        raise DemoError("--workers", "--workers, --executor and --address run DAgger's rollouts: use them with --algo dagger")
    if algo not in FAMILY and algo_opt:
        raise DemoError("--algo-opt", f"sets an option of {', '.join(FAMILY[1:])}, not of {algo!r}")
    if nproc < 1:
        raise DemoError("--nproc", f"must be at least 1, got {nproc}")
    if distil is not None and (algo != "diffusion" or max(nproc, distributed.env_world_size()) > 1):
        raise DemoError("--distil", "distils a diffusion run into a diffusion student in one process: use --algo diffusion, "
                                    "without --nproc")
    if algo in FAMILY and max(nproc, distributed.env_world_size()) > 1:
        raise DemoError("--nproc", f"{algo} trains in one process (its rollouts and store are not data-parallel)")
    if nproc > 1 and distributed.env_world_size() == 1:  # not yet under torchrun: become its N processes
        from demo.training.trainer import check_run_directory

        check_run_directory(out, resume, overwrite)  # refused here in one line, not once per process
        raise typer.Exit(distributed.launch(_without_nproc(shlex.split(invocation())[1:]), nproc))
    given = dict(
        data=str(stores[0]) if len(stores) == 1 else tuple(str(s) for s in stores),  # several: their union
        out=str(out), policy=_with_head(parse_policy_opts(policy_opt), head, algo), seed=seed, steps=steps,
        batch_size=batch_size, lr=lr, weight_decay=weight_decay, warmup_steps=warmup, ema=ema, n_obs=n_obs,
        chunk=chunk, execute=execute, ensemble=ensemble, ensemble_decay=ensemble_decay, candidates=candidates, obs_keys=_obs_keys(obs_keys),
        obs_noise=obs_noise, relative_actions=not absolute_actions, train_mask=train_mask, val_mask=val_mask,
        val_fraction=val_fraction, include_failures=include_failures, eval_every=eval_every if eval_episodes else 0,
        eval_episodes=max(1, eval_episodes), eval_final=eval_episodes > 0, threads=threads,
        robot=str(robot) if robot else None, device=device,
        encoder={k: v for k, v in (("backbone", encoder), ("crop", crop)) if v is not None},
    )
    if algo in FAMILY:
        from demo.executor import ExecutorConfig
        from demo.imitation.dagger import DaggerConfig, learner_config, make_family, train_dagger

        dconfig = DaggerConfig(train=learner_config(**given), task=task, rounds=rounds, episodes_per_round=episodes_per_round,
                               round_steps=round_steps, warm_start=warm_start, beta=beta, gate=gate,
                               max_labels=max_labels)
        dconfig.check()
        family = make_family(algo, parse_policy_opts(algo_opt, "--algo-opt"))
        with bars() as progress:
            summary = train_dagger(dconfig, executor=ExecutorConfig(executor, workers, address), progress=progress,
                                   resume=resume, overwrite=overwrite, command=invocation(), family=family)
    elif distil is not None:
        from demo.training.config import TrainConfig
        from demo.imitation.distill import train as train_distil

        with bars() as progress:  # the student's settings are resolved from the teacher's
            summary = train_distil(TrainConfig(algo=algo, **given), distil, progress=progress, resume=resume,
                                   overwrite=overwrite, command=invocation())
    else:
        config = for_policy(algo, **given)
        config.check()
        with bars() as progress:
            summary = train_bc(config, progress=progress, resume=resume, overwrite=overwrite, command=invocation())
    rows = [
        ("run", summary["out"]),
        ("algo", algo),
        ("steps", summary["step"]),
        ("train loss", summary["train_loss"]),
        ("validation loss", summary["val_loss"] if summary["val_loss"] is not None else "-"),
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
