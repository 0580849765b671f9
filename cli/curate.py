"""`demo curate STORE --out STORE`: drop failed, idle, jerky, inconsistent, duplicate episodes; trim idle.

Also registers `demo bench curate`.
"""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from demo.cli.main import app
from demo.cli.options import json_option, overwrite_option, store_argument
from demo.cli.output import kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.curate import report as rep
from demo.curate.curate import CurateConfig, curate as run_curate
from demo.curate.report import episode_table_rows
from demo.curate.signals.consistency import ConsistencyParams
from demo.curate.signals.duplicates import DuplicateParams
from demo.curate.signals.idle import IdleParams
from demo.errors import DemoError

OFF = ("off", "none", "no")


def _threshold(value: str | None, flag: str) -> float | None:
    """A number, or ``off`` to switch the filter off."""
    if value is None or value.strip().lower() in OFF:
        return None
    try:
        return float(value)
    except ValueError:
        raise DemoError(flag, f"expected a number or 'off', got {value!r}") from None


@app.command()
def curate(
    source: str = store_argument("Store to curate (never modified, except by --mask)."),
    out: str = typer.Option(None, "--out", "-o", metavar="STORE", help="Write the kept (trimmed) episodes to this new store.",
                             show_default="none"),
    mask: str = typer.Option(None, "--mask", metavar="NAME",
                             help="Write score.* columns, the drop reasons and mask.NAME (= kept) into the source store.",
                             show_default="none"),
    json_out: str = json_option("the report (every episode's decision and reasons)"),
    plot: Path = typer.Option(None, "--plot", metavar="PNG", help="Write a PNG of the signal distributions with the thresholds.",
                              show_default="none"),
    drop_failed: bool = typer.Option(True, "--drop-failed/--keep-failed", help="Drop episodes whose success flag is false."),
    trim_idle: bool = typer.Option(True, "--trim-idle/--no-trim-idle", help="Cut idle runs at the start/end of kept episodes."),
    max_idle: str = typer.Option("0.2", help="Max fraction of (trimmed) frames in mid-episode pauses, or 'off'."),
    max_jerk: str = typer.Option(
        "400", help="Max jerk of the commanded action trajectory (its 3rd time-derivative, each dimension in its "
                    "typical range, RMS over non-gripper dimensions, 75th percentile over frames) in range/s^3, or 'off' (at "
                    "400, off for a Gymnasium environment's own command: its units are unknown)."
    ),
    min_consistency: str = typer.Option("0.5", help="Min share of sampled frames agreeing with other episodes, or 'off'."),
    max_novelty: str = typer.Option("off", help="Max mean distance to other episodes' states (normalised obs units), or 'off'."),
    max_length_z: str = typer.Option("3.5", help="Max robust z of log length within the task (too long only), or 'off'."),
    dedupe: bool = typer.Option(True, "--dedupe/--no-dedupe", help="Keep only the first of (near-)duplicate episodes."),
    dedupe_tol: float = typer.Option(0.003, help="Duplicate tolerance: RMS fingerprint difference in typical-range units."),
    min_time_left: str = typer.Option("off", help="Near-miss: drop successes with less time to the horizon (s), or 'off'."),
    min_margin: str = typer.Option("off", help="Near-miss: drop successes with a success margin below this (task units), or 'off'."),
    idle_speed: float = typer.Option(0.02, help="Idle when every dimension moves slower than this (range/s)."),
    min_pause: float = typer.Option(0.5, help="Shortest idle run that counts as a pause or an idle start/end (s)."),
    neighbours: int = typer.Option(8, "--neighbours", "-k", help="Nearest frames of other episodes per query frame."),
    agree_factor: float = typer.Option(
        3.0, help="A sampled frame agrees when its action deviates from the other episodes' consensus by <= this x their spread."
    ),
    seed: int = typer.Option(0, help="Seed of the query-frame sampling."),
    show: str = typer.Option("auto", help="Episodes in the table: all, dropped, none, auto (all up to 40 episodes)."),
    overwrite: bool = overwrite_option("an existing --out store"),
) -> None:
    """Find and drop failed, idle, jerky, inconsistent and duplicate episodes; trim idle starts/ends."""
    if show not in ("auto", "all", "dropped", "none"):
        raise DemoError("--show", f"expected all, dropped, none or auto, got {show!r}")
    if neighbours < 1:
        raise DemoError("--neighbours", "must be >= 1")
    config = CurateConfig(
        drop_failed=drop_failed,
        trim_idle=trim_idle,
        max_idle=_threshold(max_idle, "--max-idle"),
        max_jerk=_threshold(max_jerk, "--max-jerk"),
        min_consistency=_threshold(min_consistency, "--min-consistency"),
        max_novelty=_threshold(max_novelty, "--max-novelty"),
        max_length_z=_threshold(max_length_z, "--max-length-z"),
        dedupe=dedupe,
        min_time_left_s=_threshold(min_time_left, "--min-time-left"),
        min_margin=_threshold(min_margin, "--min-margin"),
        idle=IdleParams(speed=idle_speed, min_run_s=min_pause),
        consistency=ConsistencyParams(k=neighbours, agree_factor=agree_factor, seed=seed),
        duplicates=DuplicateParams(tol=dedupe_tol),
    )
    config.validate()
    with bars() as progress:
        curation = run_curate(source, out, mask=mask, config=config, overwrite=overwrite, progress=progress)
    result = rep.build(curation, source=source, out=out, mask=mask)
    if plot:
        rep.plot(curation, plot)
    shown = report_console(json_out)
    _print(shown, result, show)
    written = [f"{out} ({result['summary']['kept']} episodes)" if out else "", f"mask.{mask} in {source}" if mask else ""]
    written += [str(json_out) if json_out not in (None, "-") else "", str(plot) if plot else ""]
    shown.print("wrote: " + (", ".join(w for w in written if w) or "nothing (analysis only: pass --out or --mask)"),
                highlight=False)
    write_json(result, json_out)


def _print(shown: Console, result: dict, show: str) -> None:
    s = result["summary"]
    if show == "auto":
        show = "all" if s["episodes"] <= 40 else "dropped"
    rows, left = episode_table_rows(result, show)
    if rows:
        shown.print(table(f"episodes ({show})", ["#", "operator", "success", "frames", "decision", "trim", "reasons"], rows))
        if left:
            shown.print(f"... and {left} more (see --json)")
    by_reason = ", ".join(f"{k}: {v}" for k, v in s["dropped_by_reason"].items() if v) or "-"
    shown.print(
        kv_table(
            "curation",
            [
                ("kept", f"{s['kept']} / {s['episodes']} episodes, {s['frames_out']} / {s['frames_in']} frames"),
                ("dropped", f"{s['dropped']} ({by_reason}; an episode may have several reasons)"),
                ("trimmed", f"{s['trimmed']} kept episodes had idle start/end frames cut"),
            ],
        )
    )
    ops = result["operators"]
    if len(ops) > 1 or (ops and ops[0]["operator"] != "(none)"):
        shown.print(
            table(
                "kept and dropped per operator",
                ["operator", "episodes", "failed", "kept", "dropped", "dropped for"],
                [
                    (r["operator"], r["episodes"], r["failed"], f"{r['kept']} ({r['kept_share']:.0%})",
                     f"{r['episodes'] - r['kept']} ({r['dropped_share']:.0%})",
                     ", ".join(f"{k} {v}" for k, v in r["dropped_for"].items()) or "-")
                    for r in ops
                ],
            )
        )
