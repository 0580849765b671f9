"""`demo teleop --mode kinesthetic|vr`: live teleoperation in the browser; `demo bench retarget`."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from demo.cli.bench import bench_app
from demo.cli.main import app
from demo.cli.options import json_option, robot_option
from demo.cli.output import console, err_console, kv_table, report_console, write_json


@app.command()
def teleop(
    mode: str = typer.Option("vr", help="kinesthetic (drag the backdrivable arm) or vr (move a hand gizmo)."),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    out: str = typer.Option(None, "--out", "-o", metavar="STORE", help="Store to append saved episodes to (created if missing).",
                             show_default="none: nothing is saved"),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states."),
    operator: str = typer.Option("human", help="Who demonstrates (the episode table's operator column)."),
    ik: str = typer.Option("mink", help="VR mode IK backend: mink or placo."),
    robot: Path = robot_option(),
    host: str = typer.Option("127.0.0.1", help="Address to listen on (127.0.0.1: this machine only)."),
    port: int = typer.Option(8080, "--port", "-p", help="Port (0 picks a free one)."),
) -> None:
    """Live teleoperation in the browser (viser): Start / Stop & save / Discard, gripper buttons."""
    from demo.collect.teleop import TeleopConfig, serve_teleop

    config = TeleopConfig(mode=mode, task=task, out=str(out) if out else None, seed=seed, operator=operator, ik=ik,
                          robot=str(robot) if robot else None, host=host, port=port)
    session = serve_teleop(config)
    try:
        if host not in ("127.0.0.1", "localhost", "::1"):
            err_console.print(f"[bold yellow]warning:[/] listening on {host}: other machines can drive the robot")
        if out is None:
            err_console.print("[yellow]note:[/] no --out: episodes are not saved")
        console.print(f"demo teleop ({mode}): {session.url}  (Ctrl-C to stop)", highlight=False)
        while True:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        saved = session.saved
        session.close()
    console.print(f"demo teleop: stopped, {saved} episode(s) saved" + (f" to {out}" if out else ""))


@bench_app.command("retarget")
def bench_retarget(
    json_out: str = json_option(default="-"),
    task: str = typer.Option("pick", help="Task whose scene the hand poses are retargeted in."),
    seconds: float = typer.Option(2.0, help="Timing budget per measurement (s)."),
    ik: list[str] = typer.Option(["mink", "placo"], help="IK backends to measure (repeatable)."),
    seed: int = typer.Option(0, help="Seed of the initial state and the hand path."),
) -> None:
    """VR retargeting poses/s on one core vs the bare IK solve, mink and placo."""
    from demo.bench.retarget import run
    from demo.collect.retarget import IK_BACKENDS
    from demo.errors import DemoError

    for name in ik:
        if name not in IK_BACKENDS:
            raise DemoError("--ik", f"unknown IK backend {name!r} (choose from {', '.join(IK_BACKENDS)})")
    r = run(task=task, seconds=seconds, backends=tuple(ik), seed=seed)
    rows = []
    for name, b in r["backends"].items():
        rows += [
            (f"{name}: retargeted poses/s (target >= {r['target_poses_per_s']:.0f})", b["poses_per_s"]),
            (f"{name}: bare IK solves/s (reference)", b["reference_bare_solves_per_s"]),
            (f"{name}: one pose costs (bare solves)", b["pose_cost_in_bare_solves"]),
        ]
    report_console(json_out).print(kv_table(f"bench retarget ({task})", rows))
    write_json(r, json_out)
