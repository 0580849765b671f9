"""Registers every subcommand on the app: one module per command or command group, imported for
its ``@app.command()`` side effect, in the order ``demo --help`` lists them."""

from __future__ import annotations

from demo.cli import bench, collect, info, quickstart  # noqa: F401
from demo.cli import export, import_, view  # noqa: F401  (interop, view)
from demo.cli import curate  # noqa: F401
from demo.cli import convert  # noqa: F401
from demo.cli import teleop  # noqa: F401
from demo.cli import train, eval  # noqa: F401
from demo.cli import robot  # noqa: F401  (robot check)
from demo.cli import irl  # noqa: F401  (irl train: PPO, GAIL, AIRL, linear IRL)
