"""Diffusion policy commands: `demo bench infer` (latency per action chunk), `demo bench multimodal` (avoid paths, PNG)."""

from __future__ import annotations

import typer

from demo.cli.bench import bench_app
from demo.cli.options import RUN, device_option, json_option


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
    from demo.bench.infer import run as run_bench
    from demo.cli.output import report_console, table, write_json
    from demo.errors import DemoError

    try:
        chans = tuple(int(c) for c in channels.split(",")) if channels else None
    except ValueError:
        raise DemoError("--channels", f"{channels!r} is not a comma-separated list of integers") from None
    try:
        r = run_bench(run=run, denoiser="unet" if (large or chans) else denoiser, large=large, channels=chans,
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


@bench_app.command("multimodal")
def bench_multimodal(
    diffusion: str = typer.Option(..., "--diffusion", metavar=RUN, help="Diffusion run directory (trained on avoid)."),
    reference: str = typer.Option(..., "--reference", metavar=RUN, help="Reference run directory, e.g. MSE-BC on the same data."),
    starts: int = typer.Option(20, help="Start states (demo eval's seed stream)."),
    samples: int = typer.Option(3, help="Episodes per start state, each with another policy sampling seed."),
    seed: int = typer.Option(0, help="Evaluation seed (as demo eval --seed)."),
    execute: int = typer.Option(None, help="Actions executed per chunk by the diffusion run.", show_default="the run's own"),
    reference_execute: int = typer.Option(None, help="Actions executed per chunk by the reference run.",
                                          show_default="the run's own"),
    png: str = typer.Option("multimodal.png", "--png", help="Where to draw the end-effector paths."),
    json_out: str = json_option(default="-"),
) -> None:
    """avoid: EE paths of two policies from the same start states, which side they pass, PNG + JSON."""
    from demo.experiments.multimodal import run as run_modes
    from demo.cli.output import report_console, table, write_json

    r = run_modes(diffusion, reference, starts=starts, samples=samples, seed=seed, png=png, execute=execute,
                  reference_execute=reference_execute)
    rows = []
    for s in (r["figure"], r["reference"]):
        m = s["modes"]
        rows.append((f"{s['algo']} (execute {s['execute']})", f"{s['success_rate']:.1%}", m["left"], m["right"], m["none"],
                     f"{s['starts_with_both_modes']}/{starts}"))
    report_console(json_out).print(table(f"bench multimodal ({starts} starts x {samples} samples) -> {r.get('png')}",
                                         ["policy", "success", "left", "right", "none", "starts with both modes"], rows))
    write_json(r, json_out)
