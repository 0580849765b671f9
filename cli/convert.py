"""`demo convert STORE --to REPR`: actions in another representation (new store, replay check,
round trip). Also registers `demo bench convert`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer
from rich.console import Console

from demo.cli.main import app
from demo.cli.options import json_option, mask_option, overwrite_option, robot_option, store_argument
from demo.cli.output import kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.convert.arms import arms_replay_check, convert_arms_store
from demo.convert.check import CheckReport, replay_check, round_trip
from demo.convert.convert import ConvertOptions, convert_store
from demo.convert.representations import get_representation
from demo.errors import DemoError
from demo.progress import Progress
from demo.sim.arms import lists_arms
from demo.store import EpisodeStore


@app.command()
def convert(
    source: str = store_argument("Store whose actions to convert (never modified)."),
    to: str = typer.Option(..., "--to", help="Target representation: joint_pos, joint_vel, ee_abs, ee_delta, ee7."),
    out: str = typer.Option(None, "--out", "-o", metavar="STORE", help="Write the converted store here.",
                             show_default="none: only --check / --round-trip"),
    rotation: str = typer.Option(None, "--rotation", help="Rotation form: euler, rotvec, rot6d (ee_abs also quat).",
                                 show_default="the representation's own"),
    delta_frame: str = typer.Option(None, "--delta-frame", help="ee_delta: compose deltas in the 'base' or 'ee' frame.",
                                    show_default="the representation's own"),
    robot: Path = robot_option("Robot config TOML to use instead of the one the store names.", "the store's robot"),
    check: bool = typer.Option(False, "--check", help="Replay original and converted actions in the simulator."),
    round_trip_: bool = typer.Option(False, "--round-trip", help="Convert there and back twice; report the EE error."),
    mask: str = mask_option("--check/--round-trip: only the episodes of this store mask."),
    episodes: int = typer.Option(None, "--episodes", help="--check/--round-trip: at most this many episodes (the first).",
                                 show_default="all"),
    json_out: str = json_option(),
    overwrite: bool = overwrite_option("an existing --out store"),
) -> None:
    """Re-express actions in another representation (ee7, ee_abs, joint_pos, ...)."""
    get_representation(to)
    if out is None and not check and not round_trip_:
        raise DemoError("--out", "say where to write the converted store (or run --check / --round-trip)")
    if episodes is not None and episodes < 1:
        raise DemoError("--episodes", f"must be at least 1, got {episodes}")
    opts = ConvertOptions(to=to, rotation=rotation, delta_frame=delta_frame, robot=str(robot) if robot else None)
    selection = _selection(source, mask, episodes)
    shown = report_console(json_out)
    results: dict[str, Any] = {}
    if robot is not None and lists_arms(robot):  # a robot of several arms: ee7 for each
        if to != "ee7" or rotation or delta_frame or round_trip_:
            raise DemoError("--to", f"{robot} has several arms: it converts --to ee7 (each arm's, concatenated), with "
                                    "--check and --out")
        with bars() as progress:
            if out is not None:
                results["convert"] = convert_arms_store(source, out, str(robot), overwrite=overwrite, progress=progress)
                shown.print(kv_table("converted", [(k, v) for k, v in results["convert"].items()]))
            if check:
                report = arms_replay_check(source, str(robot), episodes=selection, progress=progress)
                results["check"] = _show_check(report, shown)
        write_json(results, json_out)
        return
    with bars() as progress:
        if out is not None:
            results["convert"] = _run_convert(source, out, opts, overwrite, progress, shown)
        if round_trip_:
            results["round_trip"] = _run_round_trip(source, opts, selection, progress, shown)
        if check:
            results["check"] = _run_check(source, opts, selection, progress, shown)
    write_json(results, json_out)


def _selection(source: str, mask: str | None, episodes: int | None) -> Any:
    """The episodes --check/--round-trip read: the mask's (or all), then at most ``episodes`` of them."""
    if mask is None and episodes is None:
        return None
    with EpisodeStore.open(source) as store:
        chosen = store.select(mask)
    return chosen if episodes is None else chosen[:episodes]


def _run_convert(source: str, out: str, opts: Any, overwrite: bool, progress: Progress,
                 shown: Console) -> dict[str, Any]:
    result = convert_store(source, out, opts, overwrite=overwrite, progress=progress)
    rows: list[tuple[str, Any]] = [
        ("store", result.path),
        ("actions", f"{result.source} -> {result.target}"),
        ("episodes", result.episodes),
        ("frames", result.frames),
        ("seconds", f"{result.seconds:.2f} (end to end, store I/O included; `demo bench convert` times the math)"),
        ("anchor", ", ".join(f"{k}: {v}" for k, v in result.anchor_source.items())),
    ]
    if result.fk_check:
        rows.append(("FK vs mj_kinematics", f"{result.fk_check['max_pos_err_m']:.1e} m, "
                                            f"{result.fk_check['max_rot_err_rad']:.1e} rad"))
    if result.ik:
        ik = result.ik
        rows += [
            ("IK converged", f"{ik.converged}/{ik.frames} frames ({ik.converged_share:.2%})"),
            ("IK error (converged)", f"{ik.max_pos_err:.1e} m, {ik.max_rot_err:.1e} rad"),
        ]
        if ik.failed:
            failed = "; ".join(f"ep {e}: {v[:5]}{'...' if len(v) > 5 else ''}" for e, v in list(ik.failed.items())[:5])
            rows.append(("IK not converged", failed))
    shown.print(kv_table("converted", rows))
    return result.to_json()


def _run_round_trip(source: str, opts: Any, selection: Any, progress: Progress, shown: Console) -> dict[str, Any]:
    rt = round_trip(source, opts, episodes=selection, progress=progress)
    ik = rt.ik
    rows = [
        ("chain", f"{rt.source} -> {rt.target} -> {rt.source} -> {rt.target}"),
        ("frames", rt.frames),
        ("IK converged", f"{ik['converged']}/{ik['frames']} ({ik['converged_share']:.3%})"),
        ("max EE position error", f"{rt.max_pos_err_m:.2e} m (IK-converged frames)"),
        ("max EE rotation error", f"{rt.max_rot_err_rad:.2e} rad"),
        ("max |target'' - target|", ", ".join(f"{v:.1e}" for v in rt.max_target_diff)),
        ("FK vs mj_kinematics", f"{rt.fk_vs_mujoco['max_pos_err_m']:.1e} m, {rt.fk_vs_mujoco['max_rot_err_rad']:.1e} rad"),
    ]
    shown.print(kv_table("round trip", rows))
    return rt.to_json()


def _run_check(source: str, opts: Any, selection: Any, progress: Progress, shown: Console) -> dict[str, Any]:
    return _show_check(replay_check(source, opts, episodes=selection, progress=progress), shown)


def _show_check(report: CheckReport, shown: Console) -> dict[str, Any]:
    rows = [
        (e.episode, e.frames, f"{e.max_pos_err_m:.2e}", f"{e.max_rot_err_rad:.2e}", _yn(e.original_success),
         _yn(e.converted_success), "yes" if e.agree else "[red]no[/]", e.ik_failed_steps)
        for e in report.episodes
    ]
    shown.print(table(f"replay: {report.source} vs {report.target} from {report.replayed_from}",
                      ["episode", "frames", "pos err m", "rot err rad", "orig ok", "conv ok", "agree", "IK fails"],
                      rows))
    s = report.summary()
    share = s["converted_success_given_original"]
    shown.print(
        f"converted succeed on {s['converted_successes']}/{s['episodes']} episodes; "
        f"on {'-' if share is None else f'{share:.1%}'} of the {s['original_successes']} the originals succeed on; "
        f"max EE error {s['max_pos_err_m']:.2e} m / {s['max_rot_err_rad']:.2e} rad", highlight=False
    )
    return report.to_json()


def _yn(v: bool) -> str:
    return "yes" if v else "no"
