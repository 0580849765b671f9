"""`demo train`: behaviour cloning, DAgger (and any registered policy) into a run directory;
`demo bench train`: training throughput with the real data pipeline vs bare forward/backward."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.bench import bench_app
from demo.cli.main import app, invocation
from demo.cli.output import console, table, write_json
from demo.errors import DemoError

ALGOS = ("bc", "dagger", "diffusion")


def parse_policy_opts(items: list[str]) -> dict[str, str]:
    opts = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise DemoError("--policy-opt", f"{item!r} is not KEY=VALUE (e.g. hidden=512,512)")
        opts[key.strip()] = value.strip()
    return opts


@app.command()
def train(
    data: Path = typer.Argument(..., help="Episode store to learn from (e.g. pick.zarr)."),
    out: Path = typer.Option(..., "--out", "-o", help="Run directory to write (checkpoints, metrics, curves)."),
    algo: str = typer.Option("bc", help=f"Algorithm: {', '.join(ALGOS)}."),
    steps: int = typer.Option(None, help="Optimiser steps (DAgger: round 0) [bc: 5000]."),
    seed: int = typer.Option(0, help="Seed of initialisation, batches, split and rollouts."),
    batch_size: int = typer.Option(None, help="Windows per batch [256]."),
    lr: float = typer.Option(None, help="Peak learning rate (AdamW, warm-up then cosine) [bc: 1e-3]."),
    weight_decay: float = typer.Option(None, help="AdamW weight decay, not on biases [bc: 1e-4]."),
    warmup: int = typer.Option(None, help="Warm-up steps [500]."),
    ema: float = typer.Option(None, help="EMA decay of the weights used for evaluation (e.g. 0.999); 0 = off [bc: 0]."),
    n_obs: int = typer.Option(None, help="Observation history in frames [bc: 1]."),
    chunk: int = typer.Option(None, help="Action chunk length predicted per query, ACT-style chunking when > 1 [bc: 1]."),
    execute: int = typer.Option(None, help="Actions executed per query, receding horizon [bc: 1]."),
    ensemble: float = typer.Option(None, help="Temporal ensembling decay m (ACT: 0.01) [bc: 0.01 when --chunk > --execute]."),
    no_ensemble: bool = typer.Option(False, help="Execute the newest chunk only."),
    obs_keys: str = typer.Option(None, help="Comma-separated obs.* keys (default: low-dim keys except velocities; 'all' for every one)."),
    absolute_actions: bool = typer.Option(False, help="Predict absolute joint targets instead of targets relative to the joint positions."),
    obs_noise: float = typer.Option(0.0, help="Std of Gaussian noise on normalised observations during training."),
    policy_opt: list[str] = typer.Option([], "--policy-opt", help="Policy option KEY=VALUE (repeatable), e.g. hidden=512,512."),
    train_mask: str = typer.Option(None, help="Train on this store mask's episodes only (e.g. a curated subset)."),
    val_mask: str = typer.Option(None, help="Validation episodes = this store mask's episodes."),
    val_fraction: float = typer.Option(0.1, help="Otherwise: this fraction of episodes, drawn with the seed."),
    include_failures: bool = typer.Option(False, help="Also train on episodes that did not succeed."),
    eval_every: int = typer.Option(0, help="Roll the policy out every N steps (0 = only at the end with --eval-episodes > 0)."),
    eval_episodes: int = typer.Option(0, help="Episodes per rollout evaluation during training (0 = none)."),
    threads: int = typer.Option(1, help="Torch threads (0 = torch's default)."),
    task: str = typer.Option(None, help="dagger: the task to roll out (must be the data's; default: the data's)."),
    rounds: int = typer.Option(5, help="dagger: rounds of rollouts + aggregation + retraining."),
    episodes_per_round: int = typer.Option(10, help="dagger: learner rollouts per round."),
    round_steps: int = typer.Option(2000, help="dagger: optimiser steps of the learner trained after each round."),
    warm_start: bool = typer.Option(False, help="dagger: fine-tune the previous learner instead of training a new one per round."),
    beta: str = typer.Option("indicator", help="dagger: expert-mixing schedule indicator | linear:N | exp:P."),
    gate: str = typer.Option(None, help="HG-DAgger: deviation:THRESH (rad); the expert takes over and labels only when the learner strays."),
    resume: bool = typer.Option(False, help="Continue the run in --out from its last checkpoint."),
    overwrite: bool = typer.Option(False, help="Replace an existing run in --out."),
    json_out: str = typer.Option(None, "--json", help="Write the run summary as JSON ('-' for stdout)."),
) -> None:
    """Train a policy on a store: bc (MLP, chunking), dagger (with the task's expert), diffusion."""
    from demo.train.bc import TrainConfig, train as train_bc

    if algo not in ALGOS:
        raise DemoError("--algo", f"unknown algorithm {algo!r} (choose from {', '.join(ALGOS)})")
    policy = "bc" if algo == "dagger" else algo
    from demo.train.policy import policy_class

    given = {"steps": steps, "batch_size": batch_size, "lr": lr, "weight_decay": weight_decay, "warmup_steps": warmup,
             "ema": ema, "n_obs": n_obs, "chunk": chunk, "execute": execute, "ensemble": ensemble}
    # Flags given win; then the policy's own training defaults (e.g. diffusion's); then TrainConfig's.
    loop = {**policy_class(policy).TRAIN_DEFAULTS, **{k: v for k, v in given.items() if v is not None}}
    chunk_, execute_ = loop.get("chunk", 1), loop.get("execute", 1)
    if no_ensemble:
        loop["ensemble"] = None
    elif "ensemble" not in loop and chunk_ > execute_:
        loop["ensemble"] = 0.01  # ACT's temporal ensembling of overlapping chunks
    config = TrainConfig(
        data=str(data), out=str(out), algo=policy, policy=parse_policy_opts(policy_opt), seed=seed, **loop,
        obs_keys=_obs_keys(obs_keys), obs_noise=obs_noise, relative_actions=not absolute_actions,
        train_mask=train_mask, val_mask=val_mask, val_fraction=val_fraction, include_failures=include_failures,
        eval_every=eval_every if eval_episodes else 0, eval_episodes=max(1, eval_episodes),
        eval_final=eval_episodes > 0, threads=threads,
    )
    if threads > 0:
        import torch

        torch.set_num_threads(threads)
    if algo == "dagger":
        from demo.train.dagger import DaggerConfig, train_dagger

        dconfig = DaggerConfig(train=config, task=task, rounds=rounds, episodes_per_round=episodes_per_round,
                               round_steps=round_steps, warm_start=warm_start, beta=beta, gate=gate)
        summary = train_dagger(dconfig, resume=resume, overwrite=overwrite, command=invocation())
    else:
        summary = train_bc(config, resume=resume, overwrite=overwrite, command=invocation())
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
    if algo == "dagger":
        for r in summary["rounds"]:
            rows.append((f"round {r['round']}", f"labels {r['labels_total']}, rollout success "
                         f"{'-' if r['rollout_success'] is None else format(r['rollout_success'], '.0%')}"))
    console.print(table("trained", ["", ""], rows))
    write_json(summary, json_out)


def _obs_keys(text: str | None) -> tuple[str, ...]:
    if not text:
        return ()
    if text.strip() == "all":
        return ("all",)
    return tuple(k.strip() for k in text.split(",") if k.strip())


@bench_app.command("train")
def bench_train(
    json_out: str = typer.Option("-", "--json", help="Write results to this JSON file ('-' for stdout)."),
    data: Path = typer.Option(None, help="Store to train on (default: a synthetic store of --frames frames)."),
    frames: int = typer.Option(200_000, help="Frames of the synthetic store."),
    seconds: float = typer.Option(5.0, help="Timing budget per measurement."),
    batch_size: int = typer.Option(256),
    chunk: int = typer.Option(1),
    n_obs: int = typer.Option(1),
    hidden: str = typer.Option("512,512,512", help="MLP hidden sizes."),
    threads: int = typer.Option(1, help="Torch threads."),
    seed: int = typer.Option(0),
) -> None:
    """BC training samples/s with the real data pipeline vs the same model's bare forward/backward."""
    from demo.bench.train import run

    result = run(data=data, seconds=seconds, batch_size=batch_size, chunk=chunk, n_obs=n_obs,
                 hidden=tuple(int(h) for h in hidden.split(",")), threads=threads, frames=frames, seed=seed)
    if json_out != "-":
        console.print(
            table(
                "bench train",
                ["figure", "value"],
                [
                    ("training samples/s (store -> windows -> step)", result["samples_per_s"]),
                    ("bare forward/backward on in-memory tensors (reference)", result["reference_samples_per_s"]),
                    ("ratio", result["ratio_to_reference"]),
                    ("full step on in-memory tensors", result["in_memory_step_samples_per_s"]),
                    ("ratio to the full step", result["ratio_to_in_memory_step"]),
                    ("window sampling alone", result["sampling_only_samples_per_s"]),
                    ("target", f">= {result['target_ratio']}: {'met' if result['meets_target'] else 'NOT met'}"),
                ],
            )
        )
    write_json(result, json_out)


@bench_app.command("compounding")
def bench_compounding(
    json_out: str = typer.Option("-", "--json", help="Write results to this JSON file ('-' for stdout)."),
    out: Path = typer.Option(Path("compounding"), help="Working directory (stores, runs, PNG); reruns reuse it."),
    blocks: str = typer.Option("1,2", help="stack sizes (horizon 60 + 100 N steps)."),
    seed: int = typer.Option(0),
    demos: int = typer.Option(30, help="DAgger's initial demonstrations."),
    pool: int = typer.Option(200, help="Demonstrations collected per size at first (extended for BC's budget)."),
    rounds: int = typer.Option(20, help="DAgger rounds."),
    episodes_per_round: int = typer.Option(20, help="DAgger rollouts per round."),
    beta: str = typer.Option("linear:4", help="DAgger expert-mixing schedule (plain DAgger)."),
    gate: str = typer.Option("deviation:0.05", help="HG-DAgger gate; 'none' for plain DAgger (with --beta)."),
    steps: int = typer.Option(4000, help="Optimiser steps of BC and of DAgger's round 0."),
    round_steps: int = typer.Option(4000, help="DAgger optimiser steps per round."),
    hidden: str = typer.Option("512,512,512", help="Hidden widths of every method's MLP."),
    chunk: int = typer.Option(16, help="Chunk length of the chunked-BC line."),
    eval_episodes: int = typer.Option(100, help="Evaluation episodes per policy."),
    workers: int = typer.Option(1, help="Processes for collection and evaluation."),
) -> None:
    """Compounding errors on stack: success vs horizon for BC, DAgger and chunked BC at equal expert labels."""
    from demo.train.compounding import CompoundingConfig, format_table, run

    config = CompoundingConfig(out=str(out), blocks=tuple(int(b) for b in blocks.split(",")), seed=seed, demos=demos,
                               pool=pool, rounds=rounds, episodes_per_round=episodes_per_round, beta=beta,
                               gate=None if gate == "none" else gate, steps=steps,
                               round_steps=round_steps, hidden=tuple(int(h) for h in hidden.split(",")), chunk=chunk,
                               eval_episodes=eval_episodes, workers=workers)
    result = run(config, log=lambda text: console.print(text, highlight=False, markup=False))
    if json_out != "-":
        console.print(format_table(result), highlight=False)
    write_json(result, json_out)
