"""`demo info PATH`: what a store holds."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.output import console, table, write_json
from demo.errors import DemoError
from demo.store import EpisodeStore


@app.command()
def info(
    path: Path = typer.Argument(..., help="Store directory (e.g. pick.zarr)."),
    json_out: str = typer.Option(None, "--json", help="Write the summary as JSON to this file ('-' for stdout)."),
    check: bool = typer.Option(False, "--check", help="Read every frame and verify the per-episode checksums."),
) -> None:
    """Episodes, frames, fps, task, robot, action representation, features, success, masks."""
    with EpisodeStore.open(path) as store:
        s = store.summary()
        if check:
            problems = store.verify()
            s["check"] = {"ok": not problems, "problems": problems}
            if problems:
                raise DemoError(path, f"{len(problems)} damaged episode(s); first: {problems[0]}")
    if json_out:
        write_json(s, json_out)
        if json_out == "-":
            return
    action = s["action"]
    rows = [
        ("episodes", s["episodes"]),
        ("frames", s["frames"]),
        ("fps", s["fps"]),
        ("task", (s["task"] or {}).get("name", "-")),
        ("robot", (s["robot"] or {}).get("name", "-")),
        ("action", f"{action['name']} ({action['dim']}-D, frame {action['frame']}): {', '.join(action['names'])}"),
        ("success rate", "-" if s["success_rate"] is None else f"{s['success_rate']:.1%}"),
        ("mean length", "-" if s["mean_length"] is None else f"{s['mean_length']:.1f} frames"),
        ("sources", ", ".join(f"{k}: {v}" for k, v in s["sources"].items()) or "-"),
        ("operators", ", ".join(f"{k}: {v}" for k, v in s["operators"].items()) or "-"),
        ("masks", ", ".join(f"{k}: {v} episodes" for k, v in s["masks"].items()) or "-"),
    ]
    console.print(table(f"{path}", ["", ""], rows))
    console.print(
        table(
            "features",
            ["key", "shape", "dtype", "units", "meaning"],
            [(k, tuple(f["shape"]), f["dtype"], f["units"], f["description"]) for k, f in s["features"].items()],
        )
    )
