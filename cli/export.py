"""`demo export STORE --format lerobot|robomimic --out PATH`: hand a store to another learning stack."""

from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer
from rich.console import Console

from demo.cli.main import app
from demo.cli.options import json_option, mask_option, overwrite_option, store_argument
from demo.cli.output import err_console, kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.interop.common import InteropReport
from demo.interop.lerobot import export_lerobot
from demo.interop.robomimic import export_robomimic
from demo.interop.video import VideoSettings


class Format(str, Enum):
    lerobot = "lerobot"
    robomimic = "robomimic"


class Images(str, Enum):
    video = "video"
    embed = "embed"


def print_report(report: InteropReport, shown: Console) -> None:
    """The summary table on ``shown``; what was not carried as a warning on stderr."""
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
    shown.print(kv_table(f"{verb} {report.episodes} episodes", rows))
    if report.videos:
        shown.print(table("camera videos: round-trip pixel error |decoded - source| (0-255)",
                          ("camera", "codec", "frames", "files", "mean abs", "max abs"),
                          [(v.key, f"{v.codec} {v.pix_fmt or ''}".strip(), v.frames, v.files,
                            "-" if v.mean_abs_error is None else round(v.mean_abs_error, 3),
                            "-" if v.max_abs_error is None else v.max_abs_error) for v in report.videos]))
        for how in dict.fromkeys(v.measured for v in report.videos):
            shown.print(f"[dim]pixel error: {how}[/]", highlight=False)
    if report.extras:
        shown.print(f"[dim]carried in demo-specific metadata that {report.format} ignores:[/]", highlight=False)
        for item in report.extras:
            shown.print(f"[dim]  - {item}[/]", highlight=False)
    for item in report.notes:
        shown.print(f"[dim]note: {item}[/]", highlight=False)
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
    src: str = store_argument(),
    format: Format = typer.Option(..., "--format", "-f", help="lerobot (v3.0 folder) or robomimic (HDF5 file)."),
    out: Path = typer.Option(..., "--out", "-o", metavar="PATH", help="Output folder (lerobot) or .hdf5 file (robomimic)."),
    mask: str = mask_option("Export only the episodes of this store mask (e.g. train)."),
    images: Images = typer.Option(Images.video, "--images", help="lerobot: camera features as MP4 videos (AV1, lossy, "
                                  "LeRobot's default layout) or PNG embedded in the parquet (lossless)."),
    crf: int = typer.Option(None, "--crf", min=0, max=63, show_default="30 as LeRobot",
                            help="lerobot videos: AV1 quality, lower is closer to the source and larger."),
    overwrite: bool = overwrite_option("an existing --out of the same kind"),
    json_out: str = json_option("the report"),
) -> None:
    """Export a store to a LeRobotDataset v3.0 folder or a robomimic HDF5 file (losslessly, but for
    LeRobot's camera videos: their pixel error is measured and shown)."""
    with bars() as progress:
        if format is Format.lerobot:
            video = VideoSettings() if crf is None else VideoSettings(crf=crf)
            report = export_lerobot(src, out, overwrite=overwrite, episodes=mask, images=images.value, video=video,
                                    progress=progress)
        else:
            report = export_robomimic(src, out, overwrite=overwrite, episodes=mask, progress=progress)
    print_report(report, report_console(json_out))
    write_json(report.to_json(), json_out)
