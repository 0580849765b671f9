"""`demo info STORE`: what a store holds; `--check` reads every frame and says whether it is intact."""

from __future__ import annotations

import typer
from rich.table import Table

from demo.cli.main import app
from demo.cli.options import json_option, store_argument
from demo.cli.output import kv_table, report_console, table, write_json
from demo.errors import DemoError
from demo.sim.robot_record import describe_robot
from demo.store import EpisodeStore


@app.command()
def info(
    path: str = store_argument(),
    json_out: str = json_option("the summary"),
    check: bool = typer.Option(False, "--check", help="Read every frame and verify the per-episode checksums."),
) -> None:
    """Episodes, frames, fps, task, robot, action representation, features, success, masks."""
    with EpisodeStore.open(path) as store:
        s = store.summary()
        robot_line, robot_error = describe_robot(store.meta.robot, path)
        s["robot_status"] = {"ok": robot_error is None, "detail": robot_line}
        if check:
            problems = store.verify()
            s["check"] = {"ok": not problems, "problems": problems}
            if problems:
                raise DemoError(path, f"{len(problems)} damaged episode(s); first: {problems[0]}")
            if robot_error is not None:
                raise robot_error
    shown = report_console(json_out)
    action = s["action"]
    rows = [
        ("episodes", s["episodes"]),
        ("frames", s["frames"]),
        ("fps", s["fps"]),
        ("task", (s["task"] or {}).get("name", "-")),
        ("robot", robot_line),
        ("action", f"{action['name']} ({action['dim']}-D, frame {action['frame']}): {', '.join(action['names'])}"),
        ("success rate", "-" if s["success_rate"] is None else f"{s['success_rate']:.1%}"),
        ("mean length", "-" if s["mean_length"] is None else f"{s['mean_length']:.1f} frames"),
        ("sources", ", ".join(f"{k}: {v}" for k, v in s["sources"].items()) or "-"),
        ("operators", ", ".join(f"{k}: {v}" for k, v in s["operators"].items()) or "-"),
        *([("tasks", ", ".join(f"{k.removeprefix('env:')}: {v}" for k, v in s["tasks"].items()))]
          if len(s["tasks"]) > 1 else []),
        *([("instructions", "; ".join(f"{k!r}: {v}" for k, v in s["instructions"].items() if k))]
          if any(s["instructions"]) else []),
        ("masks", ", ".join(f"{k}: {v} episodes" for k, v in s["masks"].items()) or "-"),
    ]
    if check:
        rows.append(("check", f"ok: every frame of the {s['episodes']} episodes matches its checksum"))
    shown.print(kv_table(f"{path}", rows))
    shown.print(
        table(
            "features",
            ["key", "shape", "dtype", "units", "meaning"],
            [(k, tuple(f["shape"]), f["dtype"], f["units"], f["description"]) for k, f in s["features"].items()],
        )
    )
    if s["camera_bytes"]:
        shown.print(camera_table(s["camera_bytes"]))
    write_json(s, json_out)


def camera_table(sizes: dict) -> Table:
    """Bytes per frame of each camera feature, raw and as stored (``EpisodeStore.summary()["camera_bytes"]``)."""

    def row(name: str, size: str, b: dict) -> tuple:
        stored, ratio = b["stored_bytes_per_frame"], b["compression_ratio"]
        return (name, size, f"{b['raw_bytes_per_frame']:,}", "-" if stored is None else f"{stored:,.0f}",
                "-" if ratio is None else f"{ratio:.1f}x")

    rows = [row(k, "x".join(map(str, b["shape"])), b) for k, b in sizes["per_camera"].items()]
    rows.append(row("all cameras", "", sizes["total"]))
    return table("camera bytes per frame (stored: zstd chunks on disk)", ["key", "HxWxC", "raw", "stored", "ratio"], rows)
