"""`demo serve RUN`: the policy behind a WebSocket (observation -> action chunk, msgpack), for a robot-side
client (demo.deploy.controller); `demo bench realtime` runs the whole loop against the simulator."""

from __future__ import annotations

import signal
from pathlib import Path

import typer
from rich.markup import escape

from demo.cli.main import app
from demo.cli.options import device_option, run_argument
from demo.cli.output import console, err_console


@app.command()
def serve(
    run: Path = run_argument(),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (127.0.0.1: this machine only; "
                             "there is no authentication)."),
    port: int = typer.Option(8765, "--port", "-p", help="Port (0 picks a free one)."),
    expose: bool = typer.Option(False, "--expose", help="Allow a --host other than loopback (no authentication)."),
    device: str = device_option(),
) -> None:
    """Serve a trained policy to a robot: observation in, action chunk out (WebSocket, msgpack)."""
    from demo.deploy.server import PolicyServer, ServerConfig  # deferred: torch stays out of demo --help
    from demo.policies.device import resolve_device

    server = PolicyServer(ServerConfig(str(run), host=host, port=port, device=str(resolve_device(device)), expose=expose),
                          log=lambda line: err_console.print(f"[yellow]warning:[/] {escape(line)}", soft_wrap=True))
    prefix = server.bundle.policy.spec.prefix
    told = f"; it continues up to {prefix} committed actions sent with an observation" if prefix else ""
    console.print(f"serving {run} at {server.url}{told} (Ctrl-C stops)")
    signal.signal(signal.SIGTERM, lambda *_: server.server.shutdown())
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        err_console.print("stopped")
