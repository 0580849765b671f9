"""`demo train`: behaviour cloning, DAgger (and any registered policy) into a run directory;
`demo bench train`: training throughput with the real data pipeline vs bare forward/backward."""

from __future__ import annotations

import shlex
from pathlib import Path

import typer

from demo.experiments.compounding import CompoundingConfig
from demo.cli.bench import bench_app
from demo.cli.main import app, invocation
from demo.cli.options import (address_option, device_option, executor_option, json_option, overwrite_option,
                              robot_option, store_argument)
from demo.cli.output import kv_table, report_console, write_json
from demo.cli.progress import bars
from demo.progress import Tick
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


@bench_app.command("train")
def bench_train(
    json_out: str = json_option("the results", default="-"),
    images: bool = typer.Option(False, "--images", help="Visuomotor BC through the image pipeline (cameras) instead of state BC."),
    data: Path = typer.Option(None, metavar="STORE", help="Store to train on (with --images: one with cameras).",
                              show_default="a synthetic store of --frames frames"),
    frames: int = typer.Option(None, help="Frames of the synthetic store.", show_default="200,000; --images 10,000"),
    image_size: int = typer.Option(None, help="--images: side of the synthetic store's two square cameras.", show_default="64"),
    seconds: float = typer.Option(None, help="Timing budget of all measurements together.", show_default="5; --images 30"),
    batch_size: int = typer.Option(None, help="Windows per batch.", show_default="256; --images demo train's"),
    chunk: int = typer.Option(None, help="Actions predicted per window.", show_default="1; --images demo train's"),
    n_obs: int = typer.Option(None, help="Observation history in frames.", show_default="1; --images demo train's"),
    hidden: str = typer.Option(None, help="MLP hidden sizes.", show_default="512,512,512; --images the policy's"),
    encoder: str = typer.Option(None, metavar="small|resnet18", help="--images: image encoder per camera.", show_default="small"),
    device: str = device_option(),
    threads: int = typer.Option(1, help="Torch threads (0 = torch's default)."),
    seed: int = typer.Option(0, help="Seed of the synthetic store, initialisation and batches."),
    nproc: int = typer.Option(1, "--nproc", help="N >= 2: demo train --nproc N (DDP) against one process with N "
                              "threads, same store, global samples/s (--steps, --batch-size per process)."),
    steps: int = typer.Option(600, help="--nproc: optimiser steps of each demo train run."),
    rounds: int = typer.Option(2, help="--nproc: alternating runs of each side."),
) -> None:
    """Training samples/s with the real data pipeline vs the same model's bare forward/backward (state, or
    --images); with --nproc N, data-parallel training vs one process."""
    from demo.bench.train import run, run_images

    if nproc > 1:
        _bench_train_parallel(json_out, nproc, data, frames, batch_size, steps, rounds, seed, device)
        return
    try:
        sizes = tuple(int(h) for h in hidden.split(",")) if hidden else None
    except ValueError:
        raise DemoError("--hidden", f"{hidden!r} is not a comma-separated list of integers") from None
    given = dict(data=data, frames=frames, seconds=seconds, batch_size=batch_size, chunk=chunk, n_obs=n_obs,
                 hidden=sizes, threads=threads, seed=seed, device=device)
    if images:
        given.update(encoder=encoder, image_size=image_size)
    elif encoder is not None or image_size is not None:
        raise DemoError("--encoder" if encoder is not None else "--image-size", "applies to --images only")
    result = (run_images if images else run)(**{k: v for k, v in given.items() if v is not None})
    what = "store -> image windows -> crop -> step" if images else "store -> windows -> step"
    report_console(json_out).print(kv_table(f"bench train{' --images' if images else ''} ({result['device']})", [
        (f"training samples/s ({what})", result["samples_per_s"]),
        ("bare forward/backward on in-memory tensors (reference)", result["reference_samples_per_s"]),
        ("ratio", result["ratio_to_reference"]),
        ("full step on in-memory tensors", result["in_memory_step_samples_per_s"]),
        ("ratio to the full step", result["ratio_to_in_memory_step"]),
        ("window sampling alone", result["sampling_only_samples_per_s"]),
        ("target", f">= {result['target_ratio']}: {'met' if result['meets_target'] else 'NOT met'}"),
    ]))
    write_json(result, json_out)


def _bench_train_parallel(json_out: str, nproc: int, data: Path | None, frames: int | None, batch_size: int | None,
                          steps: int, rounds: int, seed: int, device: str) -> None:
    from demo.bench.train_parallel import run_parallel

    given = dict(data=data, frames=frames, batch_size=batch_size, steps=steps, rounds=rounds, seed=seed,
                 device=device)
    result = run_parallel(nproc, **{k: v for k, v in given.items() if v is not None})
    report_console(json_out).print(kv_table(f"bench train --nproc {nproc} ({result['device']})", [
        (f"{nproc} processes x 1 thread (DDP): samples/s", result["samples_per_s"]),
        (f"1 process x {nproc} threads (reference): samples/s", result["reference_samples_per_s"]),
        ("ratio", result["ratio_to_reference"]),
        ("1 process x 1 thread: samples/s", result["one_thread_samples_per_s"]),
        ("ratio to 1 thread", result["ratio_to_one_thread"]),
    ]))
    write_json(result, json_out)


_C = CompoundingConfig()  # the experiment's defaults live in its config dataclass


@bench_app.command("compounding")
def bench_compounding(
    json_out: str = json_option("the results", default="-"),
    out: Path = typer.Option(Path(_C.out), help="Working directory (stores, runs, PNG); reruns reuse it."),
    task: str = typer.Option(_C.task, help="Task whose horizon --option sets."),
    option: str = typer.Option(_C.option, help="The task option that sets the horizon (stack: repeat, horizon 60 + 100 N K; "
                               "blocks, 60 + 100 N)."),
    values: str = typer.Option(",".join(map(str, _C.values)), help="Values of --option, one horizon each."),
    task_opt: list[str] = typer.Option([f"{k}={v}" for k, v in _C.task_options.items()], "--task-opt", metavar="KEY=VALUE",
                                       help="The task's other options, fixed (repeatable)."),
    methods: str = typer.Option(",".join(_C.methods), help="Methods to compare (hg_dagger always runs: it sets the label budget)."),
    seed: int = typer.Option(_C.seed, help="Seed of collection, training and evaluation."),
    demos: int = typer.Option(_C.demos, help="The DAgger family's initial demonstrations."),
    pool: int = typer.Option(_C.pool, help="Demonstrations collected per value at first (extended for the budgets)."),
    rounds: int = typer.Option(_C.rounds, help="DAgger rounds."),
    episodes_per_round: int = typer.Option(_C.episodes_per_round, help="DAgger rollouts per round."),
    beta: str = typer.Option(_C.beta, help="Plain DAgger's expert-mixing schedule."),
    gate: str = typer.Option(_C.gate, help="HG-DAgger's gate (SafeDAgger's deviation threshold)."),
    steps: int = typer.Option(_C.steps, help="Optimiser steps of BC and of every family member's round 0."),
    round_steps: int = typer.Option(_C.round_steps, help="Optimiser steps per DAgger round."),
    warm_start: bool = typer.Option(_C.warm_start, "--warm-start/--no-warm-start",
                                    help="Each round fine-tunes the previous learner instead of training a new one."),
    max_labels: int = typer.Option(_C.max_labels, help="One expert-label budget for every horizon (HG-DAgger stops there); "
                                   "0: none, HG-DAgger's rounds set each horizon's budget."),
    hidden: str = typer.Option(",".join(map(str, _C.hidden)), help="Hidden widths of every method's MLP."),
    batch_size: int = typer.Option(_C.batch_size, help="Windows per batch of every method."),
    chunk: int = typer.Option(_C.chunk, help="Chunk length of the chunked-BC line."),
    noise: float = typer.Option(_C.noise, help="Fixed-noise DART line: noise on executed joint targets (rad)."),
    val_fraction: float = typer.Option(_C.val_fraction, help="Held-out demonstrations (SafeDAgger's classifier, DART's noise)."),
    candidates: int = typer.Option(_C.candidates, help="AggreVaTe: actions tried per labelled state (1: the expert's alone)."),
    sigma: float = typer.Option(_C.sigma, help="AggreVaTe's exploration noise and perturbation's displacement (rad)."),
    eval_episodes: int = typer.Option(_C.eval_episodes, help="Evaluation episodes per policy."),
    workers: int = typer.Option(_C.workers, help="Processes for collection, rollouts and evaluation."),
) -> None:
    """Compounding errors: success vs horizon for BC, BC + chunking, DART and the DAgger family at equal expert labels."""
    from demo.experiments.compounding import format_table, run

    def ints(flag: str, text: str) -> tuple[int, ...]:
        try:
            return tuple(int(x) for x in text.split(","))
        except ValueError:
            raise DemoError(flag, f"{text!r} is not a comma-separated list of integers") from None

    fixed = {k: _number(v) for k, v in parse_policy_opts(task_opt, "--task-opt").items()}
    config = CompoundingConfig(out=str(out), task=task, option=option, values=ints("--values", values), task_options=fixed,
                               methods=tuple(m.strip() for m in methods.split(",") if m.strip()), seed=seed, demos=demos,
                               pool=pool, rounds=rounds, episodes_per_round=episodes_per_round, beta=beta, gate=gate,
                               steps=steps, round_steps=round_steps, warm_start=warm_start, max_labels=max_labels or None,
                               hidden=ints("--hidden", hidden), batch_size=batch_size,
                               chunk=chunk, noise=noise, val_fraction=val_fraction, candidates=candidates, sigma=sigma,
                               eval_episodes=eval_episodes,
                               workers=workers)
    config.check()
    with bars() as progress:
        result = run(config, log=lambda text: progress(Tick("bench compounding", message=text)))
    report_console(json_out).print(format_table(result), highlight=False, markup=False)
    write_json(result, json_out)


def _number(text: str) -> int | float | str:
    """A task option's value as the number it spells, if it does."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text
