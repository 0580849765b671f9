"""Registers every subcommand on the app. A subcommand not built yet says so and exits 2."""

from __future__ import annotations

import typer

from demo.cli.main import app
from demo.cli.output import err_console

# Subcommands that exist: one module each, imported for its @app.command() side effect.
from demo.cli import bench, collect, info, quickstart  # noqa: F401,E402
from demo.cli import export, import_, view  # noqa: F401,E402  (interop, view)
from demo.cli import curate  # noqa: F401,E402
from demo.cli import convert  # noqa: F401,E402
from demo.cli import diffusion  # noqa: F401,E402  (bench infer)
from demo.cli import teleop  # noqa: F401,E402  (teleop, bench retarget)
from demo.cli import train, eval  # noqa: F401,E402  (train, eval, bench train)
from demo.cli import robot  # noqa: F401,E402  (robot check)
from demo.cli import irl  # noqa: F401,E402  (irl train: PPO, GAIL, AIRL, linear IRL)

NOT_BUILT = {
    "collect": ("Record demonstrations (scripted, kinesthetic, vr).", 3),
    "curate": ("Find and drop failed, idle, jerky, inconsistent or duplicate episodes.", 5),
    "convert": ("Re-express actions in another representation (ee7, joint_pos, ...).", 4),
    "train": ("Train a policy (bc, dagger, diffusion).", 6),
    "eval": ("Roll a trained policy out in simulation and report success.", 6),
    "export": ("Export a store to LeRobot v3.0 or robomimic HDF5.", 9),
    "import": ("Import a LeRobot v3.0 or robomimic HDF5 dataset.", 9),
    "view": ("Replay episodes in 3D in the browser (viser).", 9),
    "quickstart": ("The whole pipeline on built-in defaults.", 6),
    "teleop": ("Live kinesthetic / VR-style teleoperation in the browser.", 8),
}


def _placeholder(name: str, help_text: str, issue: int) -> None:
    def command(ctx: typer.Context) -> None:
        err_console.print(f"demo {name}: not built yet (issue #{issue}).")
        raise typer.Exit(2)

    app.command(
        name=name,
        help=f"{help_text} [not built yet]",
        context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
    )(command)


_registered = {c.name or c.callback.__name__.replace("_", "-") for c in app.registered_commands} | {
    g.name for g in app.registered_groups
}
for _name, (_help, _issue) in NOT_BUILT.items():
    if _name not in _registered:
        _placeholder(_name, _help, _issue)
