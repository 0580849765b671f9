"""`demo robot init MJCF`: write a starting robot config for an arm (see :mod:`demo.sim.robot_init`);
`demo robot check CFG`: is a robot config enough for every task (see :mod:`demo.sim.robot_check`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from demo.cli.main import app
from demo.cli.options import json_option, overwrite_option
from demo.cli.output import kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.errors import DemoError
from demo.sim.arms import lists_arms, load_arms
from demo.sim.robot_check import MIN_SUCCESS, check_robot
from demo.sim.robot_init import init_robot

robot_app = typer.Typer(help="Robot configs: write one for an arm's MJCF, check that one is enough for every task.",
                        no_args_is_help=True)
app.add_typer(robot_app, name="robot")


@robot_app.command("check")
def robot_check(
    config: Path = typer.Argument(..., metavar="TOML", help="Robot config (see the README's Robots section).", show_default=False),
    episodes: int = typer.Option(20, "--episodes", min=1, help="Expert episodes on reach and on pick."),
    targets: int = typer.Option(10, "--targets", min=1, help="Episodes per task whose targets the IK must reach."),
    seed: int = typer.Option(0, help="Seed of the episodes (as demo collect --seed)."),
    png: Path = typer.Option(None, "--png", metavar="FILE", help="Write the robot at home in the pick scene.",
                             show_default="no picture"),
    json_out: str = json_option("the report"),
) -> None:
    """DOF, joint limits, IK reach over every task's targets, the gripper closing, expert success on reach and pick
    (a robot of several arms, [[arms]]: each arm)."""
    arms = load_arms(config) if lists_arms(config) else None
    each: list[tuple[str, Any]] = list(zip(arms.arm_names, arms.arms)) if arms else [("", config)]
    shown = report_console(json_out)
    reports = []
    for name, arm in each:
        with bars() as progress:
            report = check_robot(arm, episodes=episodes, seed=seed, targets=targets, png=png and _png_for(png, name),
                                 progress=progress)
        _show(shown, report, f"arm {name}: " if name else "")
        reports.append((name, report))
    write_json({"robot": arms.name, "arms": {n: r.to_json() for n, r in reports}} if arms else reports[0][1].to_json(),
               json_out)
    for name, report in reports:
        if not report.ok:
            worst = min(report.experts, key=lambda t: report.experts[t]["rate"])
            r = report.experts[worst]
            raise DemoError(config, f"{f'arm {name!r}: ' if name else ''}the {worst} expert succeeds in "
                                    f"{r['successes']}/{r['episodes']} episodes (needs {MIN_SUCCESS:.0%}); check home, "
                                    "ee_site's axes (z out of the gripper, y along the fingers), max_joint_velocity and, "
                                    "for motor arms, pd_kp/pd_kd")


def _png_for(png: Path, arm: str) -> Path:
    """One picture per arm of a robot of several: ``home.png`` -> ``home_left.png``."""
    return png.with_name(f"{png.stem}_{arm}{png.suffix}") if arm else png


def _show(shown: Any, report: Any, prefix: str) -> None:
    shown.print(kv_table(f"{prefix}robot {report.robot}", [
        ("config", report.config),
        ("mjcf", report.mjcf),
        ("DOF", report.dof),
        ("gripper", ", ".join(report.gripper)),
        ("base pose", f"pos {report.base_pos}, quat {report.base_quat}"),
        ("gripper closes", f"{report.gripper_closes:.2f} of 1 after 1 s"),
        ("picture", report.png or "-"),
    ]))
    shown.print(table(f"{prefix}arm joints", ["joint", "lower", "upper", "actuation"],
                      [(j.name, "-" if j.lower is None else f"{j.lower:.4g}", "-" if j.upper is None else f"{j.upper:.4g}",
                        j.actuation) for j in report.joints]))
    shown.print(table(f"{prefix}IK over each task's targets (1 cm, 0.1 rad)", ["task", "reached", "rate"],
                      [(t, f"{r['reached']}/{r['targets']}", f"{r['rate']:.0%}") for t, r in report.ik.items()]))
    shown.print(table(f"{prefix}expert success", ["task", "success", "rate"],
                      [(t, f"{r['successes']}/{r['episodes']}", f"{r['rate']:.0%}") for t, r in report.experts.items()]))


@robot_app.command("init")
def robot_init(
    mjcf: Path = typer.Argument(..., metavar="MJCF", help="The arm's MJCF file.", show_default=False),
    out: Path = typer.Option(None, "--out", metavar="TOML", help="The robot config to write.",
                             show_default="MODEL_NAME.toml here"),
    gripper: Path = typer.Option(None, "--gripper", metavar="GRIPPER_MJCF",
                                 help="A parallel gripper in its own MJCF, for an arm file without one.", show_default="none"),
    mount: str = typer.Option(None, "--mount", metavar="BODY", help="The arm body --gripper mounts on.",
                              show_default="the last body of the arm's chain"),
    arm_prefix: str = typer.Option(None, "--arm-prefix", metavar="PREFIX",
                                   help="A file with several arms (a bimanual scene): the arm whose top-level body's "
                                        "name starts with PREFIX; the file's other bodies are left out.",
                                   show_default="the file holds one arm"),
    png: Path = typer.Option(None, "--png", metavar="FILE", help="Write the robot at home in the pick scene.",
                             show_default="no picture"),
    overwrite: bool = overwrite_option("an existing --out"),
    json_out: str = json_option("the report"),
) -> None:
    """Guess a robot config for an arm's MJCF: arm joints, gripper actuators and range, EE site, home, base position."""
    if mount is not None and gripper is None:
        raise DemoError(mjcf, "--mount names the arm body for --gripper; pass --gripper GRIPPER_MJCF too")
    report = init_robot(mjcf, out=out, gripper=gripper, mount=mount, png=png, overwrite=overwrite, arm_prefix=arm_prefix)
    shown = report_console(json_out)
    shown.print(table(f"joints of {Path(report.mjcf).name}", ["joint", "type", "range", "body", "role"],
                      [(j["name"], j["type"], "-" if j["range"] is None else f"{j['range'][0]:.4g} .. {j['range'][1]:.4g}",
                        j["body"], j["role"]) for j in report.joints]))
    shown.print(table("actuators", ["actuator", "kind", "drives", "role"],
                      [(a["name"], a["kind"], a["drives"], a["role"]) for a in report.actuators]))
    shown.print(table("sites", ["site", "body"], [(s["name"], s["body"]) for s in report.sites]))
    shown.print(kv_table(f"{len(report.bodies)} bodies", [("bodies", ", ".join(report.bodies))]))
    shown.print(kv_table(f"wrote {report.out}", [(k, v) for k, v in report.config.items()] + [
        ("IK from home", f"{report.reach['reached']}/{report.reach['targets']} of the tasks' poses (worst group "
                          f"{report.reach['worst_group_rate']:.0%})"),
        ("picture", report.png or "-"),
    ]))
    shown.print(table("check these", ["note"], [(n,) for n in report.notes]))
    shown.print(f"next: demo robot check {report.out} --png home.png")
    write_json(report.to_json(), json_out)
