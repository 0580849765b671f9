"""`demo teleop --mode kinesthetic|vr|leader`: live teleoperation in the browser; `demo bench retarget`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import typer

from demo.cli.main import app
from demo.cli.options import robot_option
from demo.cli.output import console, err_console
from demo.errors import DemoError
from demo.view.teleop import TeleopConfig, serve_teleop
from demo.view.teleop_arms import ArmsLeaderConfig, ArmsLeaderSession


@app.command()
def teleop(
    mode: str = typer.Option("vr", help="kinesthetic (drag the backdrivable arm), vr (move a hand gizmo) or leader "
                             "(move a leader arm by its joint sliders or its hand; the robot follows it)."),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    env: str = typer.Option(None, "--env", metavar="ENV", help="leader: a Gymnasium environment of a robot of several "
                            "arms (demo.sim.aloha_scene:transfer_cube) with --robot ARMS.toml: one leader per arm.",
                            show_default="none: the task"),
    out: str = typer.Option(None, "--out", "-o", metavar="STORE", help="Store to append saved episodes to (created if missing).",
                             show_default="none: nothing is saved"),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states."),
    operator: str = typer.Option("human", help="Who demonstrates (the episode table's operator column)."),
    ik: str = typer.Option("mink", help="VR and leader modes: IK backend, mink or placo."),
    robot: Path = robot_option(),
    host: str = typer.Option("127.0.0.1", help="Address to listen on (127.0.0.1: this machine only)."),
    port: int = typer.Option(8080, "--port", "-p", help="Port (0 picks a free one)."),
) -> None:
    """Live teleoperation in the browser (viser): Start / Stop & save / Discard, gripper buttons."""
    session: Any
    if env is not None:
        if mode != "leader" or robot is None:
            raise DemoError("--env", "live in an environment: --mode leader with --robot ARMS.toml (a robot of "
                                     "several arms), one leader per arm")
        session = ArmsLeaderSession(ArmsLeaderConfig(env=env, robot=str(robot), out=str(out) if out else None, seed=seed,
                                                     operator=operator, host=host, port=port))
    else:
        session = serve_teleop(TeleopConfig(mode=mode, task=task, out=str(out) if out else None, seed=seed,
                                            operator=operator, ik=ik, robot=str(robot) if robot else None, host=host,
                                            port=port))
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
