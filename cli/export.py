"""`demo export IN --format lerobot|robomimic --out PATH`: hand a store to another learning stack."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.output import console, err_console, table, write_json
from demo.interop.common import InteropReport


class Format(str, Enum):
    lerobot = "lerobot"
    robomimic = "robomimic"


def print_report(report: InteropReport) -> None:
    """The summary table on stdout; what was not carried as a warning on stderr."""
    verb = "exported" if report.direction == "export" else "imported"
    rows = [
        ("format", report.format),
        ("from", report.source),
        ("to", report.path),
        ("episodes", report.episodes),
        ("frames", report.frames),
    ]
    if report.direction == "export":
        rows.append(("files", "\n".join(report.files)))
    console.print(table(f"{verb} {report.episodes} episodes", ["", ""], rows))
    if report.extras:
        console.print(f"[dim]carried in demo-specific metadata that {report.format} ignores:[/]", highlight=False)
        for item in report.extras:
            console.print(f"[dim]  - {item}[/]", highlight=False)
    for item in report.notes:
        console.print(f"[dim]note: {item}[/]", highlight=False)
    if report.dropped:
        err_console.print(
            f"[bold yellow]warning:[/] {report.format} cannot carry (or demo could not read) "
            f"{len(report.dropped)} item(s):",
            highlight=False,
        )
        for item in report.dropped:
            err_console.print(f"  - {item}", highlight=False, soft_wrap=True)


@app.command()
def export(
    src: Path = typer.Argument(..., help="Store directory (e.g. pick.zarr)."),
    format: Format = typer.Option(..., "--format", "-f", help="lerobot (v3.0 folder) or robomimic (HDF5 file)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (lerobot) or .hdf5 file (robomimic)."),
    episodes: str = typer.Option(None, "--episodes", help="Export only the episodes of this mask (e.g. train)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing --out of the same kind."),
    json_out: str = typer.Option(None, "--json", help="Write the report as JSON to this file ('-' for stdout)."),
) -> None:
    """Export a store to a LeRobotDataset v3.0 folder or a robomimic HDF5 file, losslessly."""
    if format is Format.lerobot:
        from demo.interop.lerobot import export_lerobot

        report = export_lerobot(src, out, overwrite=overwrite, episodes=episodes, progress=True)
    else:
        from demo.interop.robomimic import export_robomimic

        report = export_robomimic(src, out, overwrite=overwrite, episodes=episodes, progress=True)
    if json_out == "-":
        write_json(report.to_json(), "-")
        return
    print_report(report)
    write_json(report.to_json(), json_out)
