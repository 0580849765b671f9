"""`demo view STORE [--episode K] [--port P] [--host H]`: replay a store's episodes in the browser."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.options import robot_option, store_argument
from demo.cli.output import console, err_console
from demo.view.app import serve


@app.command()
def view(
    src: str = store_argument(),
    episode: int = typer.Option(0, "--episode", "-e", help="Episode shown first."),
    port: int = typer.Option(8080, "--port", "-p", help="Port (0 picks a free one; a busy one moves to the next)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (127.0.0.1: this machine only)."),
    mjcf: Path = typer.Option(None, "--mjcf", metavar="XML", help="Draw this MJCF model instead of the store's task scene.",
                              show_default="the store's task scene"),
    robot: Path = robot_option("Robot config TOML to use when the store's robot files cannot be found.",
                               default="the robot the store records"),
    no_play: bool = typer.Option(False, "--no-play", help="Start paused."),
) -> None:
    """Replay episodes in 3D from their recorded simulator states, with curves and curation flags."""
    viewer = serve(src, host=host, port=port, episode=episode, mjcf=mjcf, robot=robot, autoplay=not no_play)
    # Ctrl-C (and SIGTERM) end the wait below even when the shell started us with SIGINT ignored.
    previous = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        if host not in ("127.0.0.1", "localhost", "::1"):
            err_console.print(f"[bold yellow]warning:[/] listening on {host}: other machines can open the viewer")
        if viewer.scene_note:
            err_console.print(f"[yellow]note:[/] {viewer.scene_note}", highlight=False)
        console.print(f"demo view: {viewer.url}  ({viewer.store.num_episodes} episodes; Ctrl-C to stop)", highlight=False)
        while True:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    console.print("demo view: stopped")


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
