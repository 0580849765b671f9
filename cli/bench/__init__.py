"""`demo bench <name>`: benchmarks written as JSON, each with its reference measured in the same run.

Each benchmark is a library function (:mod:`demo.bench` for performance, :mod:`demo.experiments`
for the training experiments) returning a JSON-able dict; these modules only register the
subcommands. The JSON goes to stdout by default (``--json -``), the table to stderr; ``--json FILE``
writes the file and prints the table on stdout.
"""

from __future__ import annotations

import typer

from demo.cli.main import app

bench_app = typer.Typer(help="Benchmarks written as JSON (figure and reference from the same run).", no_args_is_help=True)
app.add_typer(bench_app, name="bench")

from demo.cli.bench import performance, experiments  # noqa: E402,F401,I001  (register on bench_app, in this order)
