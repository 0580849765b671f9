"""`demo import IN --format lerobot|robomimic --out STORE`: bring another stack's dataset into a store."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.export import Format, print_report
from demo.cli.main import app
from demo.cli.output import write_json
from demo.errors import DemoError


def detect_format(src: Path) -> Format:
    """LeRobot for a folder with meta/info.json, robomimic for an HDF5 file."""
    if src.is_dir() and (src / "meta" / "info.json").is_file():
        return Format.lerobot
    if src.is_file():
        with open(src, "rb") as f:
            if f.read(8) == b"\x89HDF\r\n\x1a\n":
                return Format.robomimic
    if not src.exists():
        raise DemoError(src, "no such file or folder")
    raise DemoError(src, "is neither a LeRobot v3.0 folder (meta/info.json) nor a robomimic HDF5 file; pass --format")


@app.command(name="import")
def import_(
    src: Path = typer.Argument(..., help="LeRobot v3.0 dataset folder or robomimic .hdf5 file."),
    out: Path = typer.Option(..., "--out", "-o", help="Store directory to create (e.g. imported.zarr)."),
    format: Format = typer.Option(None, "--format", "-f", help="lerobot or robomimic (default: detected)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing store at --out."),
    json_out: str = typer.Option(None, "--json", help="Write the report as JSON to this file ('-' for stdout)."),
) -> None:
    """Import a LeRobot v3.0 dataset or a robomimic HDF5 file into a new store."""
    format = format or detect_format(src)
    if format is Format.lerobot:
        from demo.interop.lerobot import import_lerobot

        report = import_lerobot(src, out, overwrite=overwrite, progress=True)
    else:
        from demo.interop.robomimic import import_robomimic

        report = import_robomimic(src, out, overwrite=overwrite, progress=True)
    if json_out == "-":
        write_json(report.to_json(), "-")
        return
    print_report(report)
    write_json(report.to_json(), json_out)
