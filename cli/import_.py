"""`demo import DATASET --format lerobot|robomimic --out STORE`: bring another stack's dataset into a store."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from demo.cli.export import Format, print_report
from demo.cli.main import app
from demo.cli.options import json_option, overwrite_option
from demo.cli.output import report_console, write_json
from demo.cli.progress import bars
from demo.errors import DemoError
from demo.interop.lerobot import import_lerobot
from demo.interop.robomimic import import_robomimic
from demo.store.location import is_remote


def detect_format(src: Path) -> Format:
    """LeRobot for a folder with meta/, robomimic for an HDF5 file."""
    if src.is_dir() and os.path.lexists(src / "meta"):  # not meta/info.json: a link out must not be probed
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
    src: Path = typer.Argument(..., metavar="DATASET", help="LeRobot v3.0 dataset folder or robomimic .hdf5 file.",
                               show_default=False),
    out: str = typer.Option(..., "--out", "-o", metavar="STORE", help="Store directory to create (e.g. imported.zarr)."),
    format: Format = typer.Option(None, "--format", "-f", help="lerobot or robomimic.", show_default="detected"),
    overwrite: bool = overwrite_option("an existing store at --out"),
    json_out: str = json_option("the report"),
) -> None:
    """Import a LeRobot v3.0 dataset or a robomimic HDF5 file into a new store."""
    if is_remote(out):  # staged and swapped in by rename: a local folder only
        raise DemoError(out, "demo import writes a local store: import it here, then copy the folder to object "
                             "storage (e.g. aws s3 cp --recursive)")
    format = format or detect_format(src)
    with bars() as progress:
        if format is Format.lerobot:
            report = import_lerobot(src, out, overwrite=overwrite, progress=progress)
        else:
            report = import_robomimic(src, out, overwrite=overwrite, progress=progress)
    print_report(report, report_console(json_out))
    write_json(report.to_json(), json_out)
