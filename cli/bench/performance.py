"""`demo bench load|collect|render|faults|resume|convert|curate|retarget|train|infer`: performance benchmarks,
each the figure and its reference measured in the same run, written as JSON."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.bench.collect import run as run_collect, run_executors
from demo.bench.convert import run_bench as run_convert
from demo.bench.curate import run as run_curate
from demo.bench.faults import FaultsConfig, run as run_faults
from demo.bench.load import run as run_load
from demo.bench.render import DEFAULT_CAMERAS, run as run_render
from demo.bench.resume import KINDS as RESUME_KINDS, ResumeConfig, run as run_resume
from demo.bench.retarget import run as run_retarget
from demo.cli.bench import bench_app
from demo.cli.options import RUN, address_option, device_option, executor_option, json_option, robot_option
from demo.cli.output import kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.collect.retarget import IK_BACKENDS
from demo.errors import DemoError
from demo.executor import ExecutorConfig

_F = FaultsConfig()  # the benchmark's defaults live in its config dataclass


@bench_app.command("load")
def bench_load(
    json_out: str = json_option(default="-"),
    frames: int = typer.Option(1_000_000, help="Frames in the synthetic store."),
    seconds: float = typer.Option(3.0, help="Timing budget per measurement (s)."),
    seed: int = typer.Option(0, help="Seed of the synthetic store and the sampled windows."),
) -> None:
    """Window-sampling samples/s (batch 256, n_obs 2, H 16) vs a raw memory copy of the same bytes."""
    result = run_load(frames=frames, seconds=seconds, seed=seed)
    report_console(json_out).print(
        kv_table(
            "bench load",
            [
                ("window samples/s", result["samples_per_s"]),
                ("raw copy samples/s (reference)", result["reference_samples_per_s"]),
                ("ratio", result["ratio_to_reference"]),
                ("target", f">= {result['target_samples_per_s']}: {'met' if result['meets_target'] else 'NOT met'}"),
            ],
        )
    )
    write_json(result, json_out)


@bench_app.command("collect")
def bench_collect(
    json_out: str = json_option(default="-"),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    episodes: int = typer.Option(120, help="Episodes per measurement."),
    seconds: float = typer.Option(3.0, help="Timing budget of the raw-physics reference (s)."),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states."),
    rounds: int | None = typer.Option(None, min=1, help="Rounds of reference + 1 worker + 2 workers (--executor ray: "
                                         "2 processes + 2 Ray actors); best of each is reported.",
                                         show_default="6 (--executor ray: 2)"),
    executor: str = executor_option(),
    address: str = address_option(),
) -> None:
    """Scripted collection frames/s (1 and 2 workers) vs bare mj_step of the same scene; --executor ray: 2 Ray
    actors vs 2 worker processes."""
    ExecutorConfig(executor, 2, address).check()
    if executor == "ray":
        r = run_executors(task=task, episodes=episodes, seed=seed, rounds=rounds or 2, address=address)
        title, rows = f"bench collect --executor ray ({task})", [
            ("collection frames/s, 2 worker processes (reference)", r["process"]["frames_per_s"]),
            ("collection frames/s, 2 Ray actors", r["ray"]["frames_per_s"]),
            (f"ratio (target >= {r['target_ray_to_process']})",
             f"{r['ray_to_process']:.2f}: {'met' if r['meets_target'] else 'NOT met'}"),
            ("same bytes", r["same_bytes"]),
        ]
    else:
        r = run_collect(task=task, episodes=episodes, seconds=seconds, seed=seed, rounds=rounds or 6)
        title, rows = f"bench collect ({task})", [
            ("raw physics control steps/s (reference)", r["reference_physics"]["control_steps_per_s"]),
            ("collection frames/s, 1 worker", r["one_worker"]["frames_per_s"]),
            ("collection frames/s, 2 workers", r["two_workers"]["frames_per_s"]),
            (f"ratio to physics (target >= {r['target_ratio_to_physics']})", r["ratio_to_physics"]),
            (f"2-worker speed-up (target >= {r['target_two_worker_speedup']})", r["two_worker_speedup"]),
        ]
    report_console(json_out).print(kv_table(title, rows))
    write_json(r, json_out)


@bench_app.command("render")
def bench_render(
    json_out: str = json_option(default="-"),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    camera: list[str] = typer.Option([], metavar="NAME@WxH", help="Camera to record (repeatable).",
                                     show_default="front@64x64, wrist@64x64"),
    episodes: int = typer.Option(20, help="Episodes per collection measurement (at least 2)."),
    seconds: float = typer.Option(3.0, help="Timing budget of each bare-render reference (s)."),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states."),
    rounds: int = typer.Option(2, min=1, help="Rounds of reference + collection; best of each is reported."),
    workers: int = typer.Option(1, min=0, help="Simulation processes of the collection (as demo collect); 0 = all in "
                                               "this process."),
) -> None:
    """Collection frames/s with cameras vs bare mujoco.Renderer renders (+ physics) of the same scene."""
    r = run_render(task=task, cameras=camera or DEFAULT_CAMERAS, episodes=episodes, seconds=seconds, seed=seed,
            rounds=rounds, workers=workers)
    stored = r["camera_bytes"]["total"]
    report_console(json_out).print(
        kv_table(
            f"bench render ({task}, {' + '.join(r['cameras'])})",
            [
                ("bare render + physics frames/s (reference)", r["reference"]["frames_per_s"]),
                (f"collection frames/s (--workers {r['workers']})", r["figure"]["frames_per_s"]),
                (f"ratio (target >= {r['target_ratio']})", f"{r['ratio']:.2f}: {'met' if r['meets_target'] else 'NOT met'}"),
                *([("ratio in CPU time (this process)", r["cpu_ratio"])] if r["cpu_ratio"] is not None else []),
                ("image bytes per frame, raw / stored", f"{stored['raw_bytes_per_frame']:,} / "
                                                        f"{stored['stored_bytes_per_frame']:,.0f}"),
            ],
        )
    )
    write_json(r, json_out)


@bench_app.command("faults")
def bench_faults(
    json_out: str = json_option(default="-"),
    episodes: int = typer.Option(_F.episodes, help="Episodes each killed `reach` collection is asked for."),
    kills: int = typer.Option(_F.kills, help="Collections killed (SIGKILL) at a random time."),
    append_kills: int = typer.Option(_F.append_kills, help="`--append` collections killed at a random time."),
    races: int = typer.Option(_F.races, help="`--overwrite` (collect, convert, import in turn) of a store being appended to."),
    creates: int = typer.Option(_F.creates, help="Rounds of 3 processes creating the same new store at once."),
    max_kill_s: float = typer.Option(_F.max_kill_s, help="Kill times are uniform in [0, this] seconds after the start."),
    disk_mib: int = typer.Option(_F.disk_mib, help="Size of the tmpfs filled by the full-disk trial (as root)."),
    workers: int = typer.Option(_F.workers, help="Simulation processes of each killed collection."),
    seed: int = typer.Option(_F.seed, help="Seed of the random kill times."),
) -> None:
    """SIGKILLs, --overwrite races, concurrent creates and a full disk: stores readable, finished episodes lost (must be 0)."""
    config = FaultsConfig(episodes=episodes, kills=kills, append_kills=append_kills, races=races, creates=creates,
                          max_kill_s=max_kill_s, disk_mib=disk_mib, workers=workers, seed=seed)
    with bars() as progress:
        r = run_faults(config, progress=progress)
    columns = ["scenario", "trials", "stores readable", "no store, nothing finished", "finished episodes",
               "finished lost", "checks failed"]
    rows = [[s["scenario"], s["trials"], s["stores_readable"], s["no_store_nothing_finished"], s["finished_episodes"],
             s["finished_lost"], s["checks_failed"]] for s in r["scenarios"]]
    report_console(json_out).print(table(f"bench faults ({r['task']}, {r['seconds']:.0f} s)", columns, rows))
    write_json(r, json_out)
    if not r["ok"]:
        raise typer.Exit(1)  # a finished episode was lost, or a refusal was not one clean line


_R = ResumeConfig()


@bench_app.command("resume")
def bench_resume(
    json_out: str = json_option(default="-"),
    out: Path = typer.Option(Path(_R.out), metavar="DIR", help="Stores and runs of the trials."),
    kinds: str = typer.Option(",".join(_R.kinds), help=f"Comma-separated policy kinds: {', '.join(RESUME_KINDS)}."),
    kills: int = typer.Option(_R.kills, help="Runs killed (SIGKILL) at a random moment, in turn over the kinds."),
    steps: int = typer.Option(_R.steps, help="Training steps of every run."),
    checkpoint_every: float = typer.Option(_R.checkpoint_every, help="demo train --checkpoint-every of every run (s)."),
    seed: int = typer.Option(_R.seed, help="Seed of the data, the training and the kill times."),
) -> None:
    """demo train killed at random moments, resumed: final weights equal an uninterrupted run's; training lost per kill."""
    chosen = tuple(k for k in kinds.split(",") if k)
    unknown = sorted(set(chosen) - set(RESUME_KINDS))
    if unknown or not chosen:
        raise DemoError("--kinds", f"unknown kind(s) {', '.join(unknown) or '(none)'} (choose from {', '.join(RESUME_KINDS)})")
    config = ResumeConfig(out=str(out), kinds=chosen, kills=kills, steps=steps, checkpoint_every=checkpoint_every,
                          seed=seed)
    with bars() as progress:
        r = run_resume(config, progress=progress)
    rows = [[t["kind"], f"{t['kill_at_s']:.1f}", "yes" if t["killed"] else "finished first",
             "-" if t["saved_step"] is None else t["saved_step"], "-" if t["lost_s"] is None else f"{t['lost_s']:.2f}",
             "yes" if t["identical"] else "NO"] for t in r["trials"]]
    report_console(json_out).print(table(
        f"bench resume: {r['identical']}/{len(r['trials'])} identical, most training lost by a kill "
        f"{r['max_lost_s']:.2f} s (saves every {checkpoint_every:g} s)",
        ["kind", "kill at (s)", "killed", "resumed from step", "lost (s)", "same final weights"], rows))
    write_json(r, json_out)
    if not r["ok"]:
        raise typer.Exit(1)


@bench_app.command("convert")
def bench_convert(
    json_out: str = json_option(default="-"),
    frames: int = typer.Option(200_000, help="Frames to convert (synthetic joint trajectories of the robot)."),
    robot: Path = robot_option(),
    placo_frames: int = typer.Option(20_000, help="Frames for the per-frame placo FK loop (it is slow)."),
    seed: int = typer.Option(0, help="Seed of the synthetic trajectories."),
) -> None:
    """joint_pos -> ee7 frames/s on one core, vs a bare mj_kinematics loop and a per-frame placo FK loop."""
    result = run_convert(frames=frames, robot=str(robot) if robot else None, placo_frames=placo_frames, seed=seed)
    shown = report_console(json_out)
    rows = [(k, f"{v['frames_per_s']:,.0f}" if v.get("frames_per_s") else v.get("error", "-"), v.get("note", ""))
            for k, v in result["results"].items()]
    shown.print(table(f"bench convert ({result['frames']:,} frames, {result['cpu']})", ["what", "frames/s", "note"], rows))
    shown.print(f"joint_pos -> ee7 vs bare mj_kinematics: {result['ratio_vs_mj_kinematics']:.2f}x; "
                f"target >= {result['target_frames_per_s']:,} frames/s: "
                f"{'met' if result['target_met'] else 'NOT met'}")
    write_json(result, json_out)


@bench_app.command("curate")
def bench_curate(
    json_out: str = json_option(default="-"),
    frames: int = typer.Option(1_000_000, help="Frames in the synthetic store."),
    episode_s: float = typer.Option(10.0, help="Mean episode duration (s at 20 fps)."),
    seed: int = typer.Option(0, help="Seed of the synthetic store."),
) -> None:
    """Curation frames/s with every signal on, vs reading + normalising the same arrays."""
    r = run_curate(frames=frames, episode_s=episode_s, seed=seed)
    report_console(json_out).print(
        kv_table(
            "bench curate",
            [
                ("frames / episodes", f"{r['frames']} / {r['episodes']}"),
                ("curation frames/s (all signals)", r["frames_per_s"]),
                ("curation seconds", r["seconds"]),
                ("reference: read + normalise frames/s", r["reference_frames_per_s"]),
                ("ratio to reference", r["ratio_to_reference"]),
                ("target", f"<= {r['target_seconds_per_1m']} s per 1M frames: {'met' if r['meets_target'] else 'NOT met'}"),
            ],
        )
    )
    write_json(r, json_out)


@bench_app.command("retarget")
def bench_retarget(
    json_out: str = json_option(default="-"),
    task: str = typer.Option("pick", help="Task whose scene the hand poses are retargeted in."),
    seconds: float = typer.Option(2.0, help="Timing budget per measurement (s)."),
    ik: list[str] = typer.Option(["mink", "placo"], help="IK backends to measure (repeatable)."),
    seed: int = typer.Option(0, help="Seed of the initial state and the hand path."),
) -> None:
    """VR retargeting poses/s on one core vs the bare IK solve, mink and placo."""
    for name in ik:
        if name not in IK_BACKENDS:
            raise DemoError("--ik", f"unknown IK backend {name!r} (choose from {', '.join(IK_BACKENDS)})")
    r = run_retarget(task=task, seconds=seconds, backends=tuple(ik), seed=seed)
    rows = []
    for name, b in r["backends"].items():
        rows += [
            (f"{name}: retargeted poses/s (target >= {r['target_poses_per_s']:.0f})", b["poses_per_s"]),
            (f"{name}: bare IK solves/s (reference)", b["reference_bare_solves_per_s"]),
            (f"{name}: one pose costs (bare solves)", b["pose_cost_in_bare_solves"]),
        ]
    report_console(json_out).print(kv_table(f"bench retarget ({task})", rows))
    write_json(r, json_out)


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
    from demo.bench.train import run, run_images  # deferred: torch stays out of demo --help

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
    from demo.bench.train_parallel import run_parallel  # deferred: torch stays out of demo --help

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


@bench_app.command("infer")
def bench_infer(
    json_out: str = json_option(default="-"),
    run: str = typer.Option(None, "--run", metavar=RUN, help="A diffusion run directory.",
                            show_default="a fresh network of --denoiser/--channels/--large"),
    denoiser: str = typer.Option("mlp", help="Fresh network: mlp (light) | unet (published)."),
    large: bool = typer.Option(False, "--large", help="The published UNet size (256,512,1024); implies --denoiser unet."),
    channels: str = typer.Option(None, help="UNet channels, e.g. 64,128,256; implies --denoiser unet.",
                                 show_default="the UNet's own"),
    inference_steps: int = typer.Option(None, "--inference-steps", help="DDIM steps.", show_default="the policy's"),
    threads: int = typer.Option(1, help="Torch threads (demo eval runs policies on 1)."),
    seconds: float = typer.Option(10.0, help="Timing budget in s (all figures are timed in turn within it)."),
    episodes: int = typer.Option(None, help="With --run: success of both samplers on this many demo eval episodes (0 = skip).",
                                 show_default="100 with --run, else 0"),
    seed: int = typer.Option(0, help="Evaluation seed (as demo eval --seed)."),
    execute: int = typer.Option(None, help="With --episodes: actions executed per chunk.", show_default="the run's"),
    device: str = device_option(),
) -> None:
    """Milliseconds per action chunk (batch 1): DDIM fast path vs DDPM-100 eager (same network); 1 step vs the teacher's DDIM."""
    from demo.bench.infer import run as run_infer  # deferred: torch stays out of demo --help

    try:
        chans = tuple(int(c) for c in channels.split(",")) if channels else None
    except ValueError:
        raise DemoError("--channels", f"{channels!r} is not a comma-separated list of integers") from None
    try:
        r = run_infer(run=run, denoiser="unet" if (large or chans) else denoiser, large=large, channels=chans,
                      steps=inference_steps, threads=threads, seconds=seconds,
                      episodes=(100 if run else 0) if episodes is None else episodes, seed=seed,
                      execute=execute, device=device)
    except ValueError as exc:
        raise DemoError("bench infer", str(exc)) from None
    rows = [
        (r["figure"], r["ms_per_chunk"]),
        ("same, eager (no tracing)", r["ddim_eager_ms_per_chunk"]),
        ("DDPM 100 steps, fast path", r["ddpm_fast_path_ms_per_chunk"]),
        ("reference: " + r["reference"], r["reference_ms_per_chunk"]),
        ("speed-up vs reference (target >= 8)", f"{r['speedup_vs_reference']:.1f}x"),
        ("1 DDIM step (one-step diffusion), fast path", r["one_step_ms_per_chunk"]),
        (f"DDIM {r['teacher_steps']} steps (the teacher's sampler), fast path", r["teacher_steps_ms_per_chunk"]),
        (f"one-step speed-up (target >= {r['target_one_step_speedup']:g}; of the minima)",
         f"{r['one_step_speedup']:.1f}x ({r['one_step_speedup_of_minima']:.1f}x)"),
    ]
    if "success" in r:
        reference = f"success, reference ({r['reference_success_of']})"
        for name, key in (("success, figure", "success"), (reference, "reference_success")):
            s = r[key]
            rows.append((f"{name}, execute {s['execute']}", f"{s['successes']}/{s['episodes']} ({s['success_rate']:.1%})"))
    within = f", success within {r['target_success_points']:g} points" if "success" in r else ""
    target = f">= {r['target_one_step_speedup']:g}x in one step" if r["distilled_from"] else "<= 15 ms, >= 8x"
    rows.append((f"target {target}{within}", "met" if r["meets_targets"] else "NOT met"))
    report_console(json_out).print(
        table(
            f"bench infer ({r['denoiser']}, {r['parameters']:,} parameters"
            + (f", channels {tuple(r['channels'])}" if r["channels"] else "") + f", {r['threads']} thread(s))",
            ["figure", "ms per chunk"],
            rows,
        )
    )
    write_json(r, json_out)


@bench_app.command("samplers")
def bench_samplers(
    json_out: str = json_option(default="-"),
    steps: str = typer.Option("1,4,10", help="Flow matching's Euler steps to time (comma-separated)."),
    run: list[str] = typer.Option([], "--run", metavar="ALGO=RUN", help="A run to roll out (bc, diffusion or flow, "
                                  "repeatable): success on the same demo eval episodes, flow's at every --steps.",
                                  show_default="latency only"),
    episodes: int = typer.Option(100, help="With --run: evaluation episodes per run and setting."),
    seed: int = typer.Option(0, help="Evaluation seed (as demo eval --seed)."),
    threads: int = typer.Option(1, help="Torch threads (demo eval runs policies on 1)."),
    seconds: float = typer.Option(10.0, help="Timing budget in s (the samplers are timed in turn within it)."),
) -> None:
    """Milliseconds per action chunk (batch 1): BC's MSE head, diffusion (DDIM 8) and flow matching at 1, 4, 10 steps."""
    from demo.bench.samplers import run as run_samplers  # deferred: torch stays out of demo --help

    try:
        ks = tuple(int(k) for k in steps.split(",") if k.strip())
    except ValueError:
        raise DemoError("--steps", f"{steps!r} is not a comma-separated list of integers") from None
    runs = {}
    for item in run:
        name, sep, path = item.partition("=")
        if not sep or not path:
            raise DemoError("--run", f"{item!r} is not ALGO=RUN (e.g. flow=runs/pick_flow)")
        runs[name.strip()] = path
    r = run_samplers(steps=ks, runs=runs or None, episodes=episodes, seed=seed, threads=threads, seconds=seconds)
    rows = []
    for name, ms in r["ms_per_chunk"].items():
        s = (r.get("success") or {}).get("bc" if name == "mse" else name)
        rows.append((name, f"{ms:.2f}", f"{r['ratio_to_reference'][name]:.2f}x",
                     "-" if s is None else f"{s['successes']}/{s['episodes']} ({s['success_rate']:.0%})"))
    report_console(json_out).print(table(f"bench samplers ({r['config']['threads']} thread(s), batch 1; reference "
                                         f"{r['reference']})", ["sampler", "ms per chunk", "vs reference", "success"],
                                         rows))
    write_json(r, json_out)


@bench_app.command("env")
def bench_env(
    run: str = typer.Argument(..., metavar=RUN, help="A run trained on a Gymnasium environment (demo collect --env)."),
    episodes: int = typer.Option(50, help="Evaluation episodes per round."),
    seed: int = typer.Option(0, help="Seed of the evaluation episodes."),
    rounds: int = typer.Option(3, help="Interleaved rounds of each side; the best of each is kept."),
    json_out: str = json_option(default="-"),
) -> None:
    """The generic environment path's overhead: demo eval steps/s vs a bare Gymnasium loop, same env, policy, seeds."""
    from demo.bench.env import run as run_env  # deferred: torch stays out of demo --help

    result = run_env(run, episodes=episodes, seed=seed, rounds=rounds)
    report_console(json_out).print(kv_table("bench env", [
        ("environment", result["env"]),
        ("demo eval steps/s", f"{result['figure']['steps_per_s']:,.0f}"),
        ("bare loop steps/s", f"{result['reference']['steps_per_s']:,.0f}"),
        ("ratio (target >= 0.9)", f"{result['ratio']:.2f}"),
    ]))
    write_json(result, json_out)


@bench_app.command("realtime")
def bench_realtime(
    run: Path = typer.Argument(..., metavar="RUN", help="A trained run (its task and robot are the stand-in's)."),
    episodes: int = typer.Option(20, help="Real-time episodes per delay."),
    delays_ms: str = typer.Option("0,100,200,400", "--delays-ms", help="Injected inference delays (ms), comma-separated."),
    network_ms: float = typer.Option(20.0, "--network-ms", help="Injected network delay each way (ms)."),
    synchronous: bool = typer.Option(False, "--synchronous", help="The baseline: every step waits for its own "
                                     "observation's chunk before it acts."),
    ensemble: float = typer.Option(None, "--ensemble", metavar="M",
                                   help="Weight exp(-M age) of overlapping chunks, oldest first: M > 0 favours the "
                                        "older (ACT), M < 0 the newer.", show_default="ACT's 0.01"),
    seed: int = typer.Option(0, help="Seed of the evaluation episodes."),
    json_out: str = json_option(default="-"),
) -> None:
    """The policy server, the robot-side loop and the simulator as a real-time stand-in robot in another process: success, stalls and round trips per injected delay."""
    from demo.deploy.controller import ControlConfig  # deferred: websockets and torch
    from demo.deploy.realtime import RealtimeConfig, run_realtime

    try:
        delays = [float(d) / 1000 for d in delays_ms.split(",") if d.strip()]
    except ValueError:
        raise DemoError("--delays-ms", f"{delays_ms!r} is not a comma-separated list of numbers") from None
    control = ControlConfig(network_s=network_ms / 1000, synchronous=synchronous,
                            **({"ensemble": ensemble} if ensemble is not None else {}))
    results = []
    with bars() as progress:
        for delay in delays:
            results.append(run_realtime(RealtimeConfig(str(run), episodes=episodes, seed=seed, inference_delay_s=delay,
                                                       control=control), progress))
    rows = [[f"{r['inference_delay_ms']:.0f}", f"{r['successes']}/{r['episodes']}",
             f"{r['ci95'][0]:.0%}-{r['ci95'][1]:.0%}", f"{r['round_trip_ms']['median']:.0f}",
             f"{r['stall_steps']}/{r['steps']}", r["clipped_commands"], r["outside_workspace"], r["loop_overruns"]]
            for r in results]
    mode = "synchronous" if synchronous else "asynchronous, chunks merged"
    report_console(json_out).print(table(f"bench realtime: {run} ({mode}; {network_ms:g} ms network each way)",
                                         ["inference delay (ms)", "success", "95% CI", "round trip (ms)",
                                          "stalled steps", "clipped", "held at the workspace", "overruns"], rows))
    write_json({"run": str(run), "network_ms_each_way": network_ms, "synchronous": synchronous, "ensemble": control.ensemble,
                "results": results}, json_out)


@bench_app.command("delay")
def bench_delay(
    runs: list[Path] = typer.Argument(..., metavar="RUN", help="Trained runs, one or more (each one's task is "
                                      "simulated)."),
    delays: str = typer.Option("0,2,4,6,8,10", help="Inference delays in control steps, comma-separated (0: the "
                               "reference, every answer in time)."),
    episodes: int = typer.Option(100, help="Episodes per delay."),
    anchor: bool = typer.Option(True, "--anchor/--no-anchor", help="Start an episode's first chunk when it is first "
                                "executed (the client's rule); --no-anchor: at its observation's step."),
    prefix: bool = typer.Option(True, "--prefix/--no-prefix", help="Send the committed actions to a policy trained "
                                "with --prefix-steps (others ignore them)."),
    ensemble: float = typer.Option(0.01, "--ensemble", metavar="M", help="Weight exp(-M age) of overlapping chunks, "
                                   "oldest first (ACT: 0.01)."),
    seed: int = typer.Option(0, help="Seed of the evaluation episodes."),
    plot: Path = typer.Option(None, "--plot", metavar="PNG", help="Success against delay, one line per run.",
                              show_default="(no figure)"),
    json_out: str = json_option(default="-"),
) -> None:
    """Asynchronous chunk execution with the inference delay counted in control steps, simulated without a clock (demo.deploy.delayed): success per delay and run, in seconds rather than demo bench realtime's minutes."""
    from demo.deploy.delayed import DelayConfig, run_delayed  # deferred: torch and MuJoCo
    from demo.figures import success_lines  # deferred: matplotlib

    try:
        steps = [int(d) for d in delays.split(",") if d.strip()]
    except ValueError:
        raise DemoError("--delays", f"{delays!r} is not a comma-separated list of whole control steps") from None
    if not steps or min(steps) < 0:
        raise DemoError("--delays", f"{delays!r}: give one or more delays >= 0")
    results = []
    with bars() as progress:
        for run in runs:
            for d in steps:
                results.append(run_delayed(DelayConfig(str(run), d, episodes, seed, ensemble, anchor, prefix), progress))
    report: dict = {"anchor": anchor, "ensemble": ensemble, "results": results}
    if plot is not None:
        series = {Path(run).name: [(r["delay_steps"], r["success_rate"], *r["ci95"]) for r in results
                                        if r["run"] == str(run)] for run in runs}
        report["plot"] = str(success_lines(series, plot, "inference delay (control steps)",
                                           f"asynchronous execution, {episodes} episodes per point", steps))
    rows = [[Path(r["run"]).name, str(r["delay_steps"]), f"{r['successes']}/{r['episodes']}",
             f"{r['ci95'][0]:.0%}-{r['ci95'][1]:.0%}", str(r["prefix_steps"])] for r in results]
    report_console(json_out).print(table(f"bench delay (asynchronous, first chunk anchored "
                                         f"{'when used' if anchor else 'at its observation'})",
                                         ["run", "delay (control steps)", "success", "95% CI", "committed steps told"],
                                         rows))
    write_json(report, json_out)


@bench_app.command("serve")
def bench_serve(
    policies: str = typer.Option(",".join(("bc", "act", "diffusion")), help="Comma-separated policies to train a few "
                                 "steps and serve (latency does not depend on the weights)."),
    run: list[Path] = typer.Option(None, "--run", metavar="RUN", help="Time these trained runs instead (repeatable).",
                                   show_default="fresh runs of --policies"),
    seconds: float = typer.Option(10.0, help="Seconds per policy, figure and reference interleaved."),
    clients: int = typer.Option(4, help="Clients at once, for the throughput under load."),
    seed: int = typer.Option(0, help="Seed of the data, the training and the observation sent."),
    json_out: str = json_option(default="-"),
) -> None:
    """The policy server on CPU: round-trip latency (median, p90, p99) and queries/s per policy, against the same policy's in-process inference."""
    from demo.bench.serve import ServeBenchConfig, run as run_serve  # deferred: torch and websockets

    chosen = tuple(p.strip() for p in policies.split(",") if p.strip())
    config = ServeBenchConfig(policies=chosen, runs=tuple(str(r) for r in run or ()), seconds=seconds, clients=clients,
                              seed=seed)
    with bars() as progress:
        result = run_serve(config, progress)
    rows = [[r["policy"], f"{r['inference_ms']['median']:.2f}", f"{r['round_trip_ms']['median']:.2f}",
             f"{r['round_trip_ms']['p90']:.2f}", f"{r['round_trip_ms']['p99']:.2f}", f"{r['overhead_ms']:.2f}",
             f"{r['ratio']:.2f}", f"{r['queries_per_s']:.0f}", f"{r['queries_per_s_under_load']:.0f}"]
            for r in result["results"]]
    report_console(json_out).print(table(f"bench serve ({clients} clients under load)", [
        "policy", "inference (ms)", "round trip median", "p90", "p99", "overhead (ms)", "ratio", "queries/s",
        "queries/s under load"], rows))
    write_json(result, json_out)
