"""`demo quickstart`: collect -> curate -> convert -> train -> eval on built-in defaults."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.output import console, table, write_json


def _stage_row(name: str, r: dict, seconds: float) -> tuple[str, str, str]:
    if name == "collect":
        what = ", ".join(f"{o['episodes']} {o['operator']} ({o['success_rate']:.0%} success)" for o in r["by_operator"])
    elif name == "curate":
        what = f"kept {r['kept']} of {r['episodes']} episodes"
    elif name == "convert":
        what = (f"ee7 round trip: max {r['round_trip_max_pos_err_m']:.1e} m / {r['round_trip_max_rot_err_rad']:.1e} rad, "
                f"IK converged {r['ik_converged_share']:.1%}")
    elif name == "train":
        what = f"BC, {r['steps']} steps"
    else:
        lo, hi = r["ci95"]
        what = f"success {r['successes']}/{r['episodes']} = {r['success_rate']:.0%} (95% CI {lo:.0%}-{hi:.0%})"
    return name, what, f"{seconds:.0f} s"


@app.command()
def quickstart(
    out: Path = typer.Option(Path("quickstart"), "--out", "-o", help="Run directory for every artefact."),
    task: str = typer.Option("pick", help="Built-in task."),
    episodes: int = typer.Option(100, help="Expert demonstrations to collect."),
    poor: int = typer.Option(20, help="Extra demonstrations from a simulated poor operator (for curation)."),
    steps: int = typer.Option(5000, help="BC training steps."),
    eval_episodes: int = typer.Option(50, help="Evaluation rollouts."),
    workers: int = typer.Option(2, help="Simulation worker processes."),
    seed: int = typer.Option(0),
    overwrite: bool = typer.Option(False, help="Replace an existing run directory."),
    json_out: str = typer.Option(None, "--json", help="Write every stage's results as JSON ('-' for stdout)."),
) -> None:
    """The whole pipeline on built-in defaults: collect -> curate -> convert -> train -> eval."""
    from demo.quickstart import QuickstartConfig, run

    config = QuickstartConfig(out=str(out), task=task, expert_episodes=episodes, poor_episodes=poor, steps=steps,
                              eval_episodes=eval_episodes, workers=workers, seed=seed)
    rows = []

    def on_stage(name: str, result: dict, seconds: float) -> None:
        rows.append(_stage_row(name, result, seconds))
        console.print(f"[bold green]done[/] {rows[-1][0]}: {rows[-1][1]} ({rows[-1][2]})")

    results = run(config, on_stage=on_stage, overwrite=overwrite)
    console.print(table(f"quickstart ({task}) in {out}", ["stage", "result", "time"], rows))
    write_json(results, json_out or out / "quickstart.json")
