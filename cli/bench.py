"""`demo bench <name>`: benchmarks written as JSON, each with its reference measured in the same run.

Each benchmark is a library function in ``demo.bench.<name>`` returning a JSON-able dict; this
module only registers the subcommands.
"""

from __future__ import annotations

import typer

from demo.cli.main import app

bench_app = typer.Typer(help="Benchmarks written as JSON (figure and reference from the same run).", no_args_is_help=True)
app.add_typer(bench_app, name="bench")
