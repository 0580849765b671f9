"""`demo quickstart`: collect -> curate -> convert -> train -> eval on built-in defaults."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.options import json_option, overwrite_option
from demo.cli.progress import bars
from demo.cli.output import report_console, table, write_json
from demo.progress import Tick
from demo.quickstart import QuickstartConfig, run


def _stage_row(name: str, r: dict, seconds: float) -> tuple[str, str, str]:
    if name == "collect":
        what = ", ".join(f"{o['episodes']} {o['operator']} ({o['success_rate']:.0%} success)" for o in r["by_operator"])
    elif name == "curate":
        what = f"kept {r['kept']} of {r['episodes']} episodes"
    elif name == "convert":
        what = (f"ee7 round trip: max {r['round_trip_max_pos_err_m']:.1e} m / {r['round_trip_max_rot_err_rad']:.1e} rad, "
                f"IK converged {r['ik_converged_share']:.1%}")
    elif name == "train":
        what = f"BC, {r.get('step', r['steps'])} steps"
    else:
        lo, hi = r["ci95"]
        what = f"success {r['successes']}/{r['episodes']} = {r['success_rate']:.0%} (95% CI {lo:.0%}-{hi:.0%})"
    return name, what, f"{seconds:.0f} s"


_Q = QuickstartConfig()  # the defaults live in the library's config


@app.command()
def quickstart(
    out: Path = typer.Option(Path(_Q.out), "--out", "-o", metavar="DIR", help="Run directory for every artefact."),
    task: str = typer.Option(_Q.task, help="Built-in task."),
    episodes: int = typer.Option(_Q.expert_episodes, help="Expert demonstrations to collect."),
    poor: int = typer.Option(_Q.poor_episodes, help="Extra demonstrations from a simulated poor operator (for curation)."),
    steps: int = typer.Option(None, help="BC training steps.", show_default="BC's default"),
    eval_episodes: int = typer.Option(_Q.eval_episodes, help="Evaluation rollouts."),
    workers: int = typer.Option(_Q.workers, help="Simulation worker processes."),
    seed: int = typer.Option(_Q.seed, help="Seed of collection, training and evaluation."),
    overwrite: bool = overwrite_option("an existing run directory at --out"),
    json_out: str = json_option("every stage's results", unset="DIR/quickstart.json"),
) -> None:
    """The whole pipeline on built-in defaults: collect -> curate -> convert -> train -> eval."""
    config = QuickstartConfig(out=str(out), task=task, expert_episodes=episodes, poor_episodes=poor, steps=steps,
                              eval_episodes=eval_episodes, workers=workers, seed=seed)
    shown = report_console(json_out)
    rows = []
    with bars() as progress:

        def on_stage(name: str, result: dict, seconds: float) -> None:
            rows.append(_stage_row(name, result, seconds))
            progress(Tick("quickstart", message=f"done {rows[-1][0]}: {rows[-1][1]} ({rows[-1][2]})"))

        results = run(config, on_stage=on_stage, overwrite=overwrite, progress=progress)
    shown.print(table(f"quickstart ({task}) in {out}", ["stage", "result", "time"], rows))
    write_json(results, json_out or out / "quickstart.json")
