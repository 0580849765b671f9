"""The parameters every command spells the same way: ``STORE``, ``RUN``, ``--json FILE|-``, ``--overwrite``,
``--mask NAME``, ``--robot``, ``--executor``/``--address``.

Each function returns a fresh typer parameter (typer needs one object per use) so a command reads
``store: str = store_argument("Store to curate (never modified).")``.
"""

from __future__ import annotations

import json
from typing import Any

import typer

from demo.errors import DemoError

STORE = "STORE"
RUN = "RUN"
JSON_HELP = "Write {what} as JSON to FILE; '-' prints it to stdout, which then holds only the JSON."


def store_argument(help: str = "Episode store: a directory (e.g. pick.zarr) or a URL (s3://bucket/pick.zarr).") -> Any:
    """The positional store of a command that reads one. Declare it ``str``, not ``Path``: a Path
    would turn ``s3://bucket/x`` into ``s3:/bucket/x`` (see :mod:`demo.store.location`)."""
    return typer.Argument(..., metavar=STORE, help=help, show_default=False)


def run_argument(help: str = "Run directory written by demo train.") -> Any:
    """The positional run directory of a command that reads one."""
    return typer.Argument(..., metavar=RUN, help=help, show_default=False)


def json_option(what: str = "the results", default: str | None = None, unset: str = "no JSON") -> Any:
    """``--json FILE|-``; benchmarks default to ``-`` (their result is the JSON). ``unset``: what
    happens without the flag, for the help."""
    return typer.Option(default, "--json", metavar="FILE|-", help=JSON_HELP.format(what=what),
                        show_default=default if default is not None else unset)


def overwrite_option(what: str = "an existing --out") -> Any:
    """A plain ``--overwrite`` flag (no ``--no-overwrite``)."""
    return typer.Option(False, "--overwrite", help=f"Replace {what}.")


def mask_option(help: str = "Only the episodes of this store mask (see demo info).") -> Any:
    """``--mask NAME``: a subset of a store's episodes (``--episodes`` is always a count)."""
    return typer.Option(None, "--mask", metavar="NAME", help=help, show_default="every episode")


def robot_option(help: str = "Robot config TOML.", default: str = "the built-in arm") -> Any:
    return typer.Option(None, "--robot", metavar="TOML", help=help, show_default=default)


def device_option() -> Any:
    return typer.Option("auto", metavar="auto|cpu|cuda|mps",
                        help="Torch device: auto takes a CUDA GPU, else MPS, else the CPU (mixed precision on CUDA).")


def executor_option() -> Any:
    """``--executor process|ray``: where a command's ``--workers`` run (:mod:`demo.executor`)."""
    return typer.Option("process", "--executor", metavar="process|ray",
                        help="Where the --workers run: processes of this machine, or Ray actors on a Ray cluster "
                             "(a local one unless --address; pip install -e '.\\[ray]'). Same results either way.")


def address_option() -> Any:
    """``--address ADDR``: the Ray cluster of ``--executor ray``."""
    return typer.Option(None, "--address", metavar="ADDR",
                        help="--executor ray: the Ray cluster to run on (e.g. auto, ray://HOST:10001).",
                        show_default="a local Ray with --workers CPUs")


def env_option() -> Any:
    return typer.Option(None, "--env", metavar="ENV", help="A Gymnasium environment: a registered id (CartPole-v1), "
                        "module:id (imports the module that registers it) or module:factory.", show_default="none")


def env_opt_option() -> Any:
    return typer.Option([], "--env-opt", metavar="KEY=VALUE", help="--env: a keyword argument of the environment "
                        "(repeatable; VALUE read as JSON where it parses, else as text); max_episode_steps=N sets the "
                        "horizon of one that has none.", show_default="none")


def task_opt_option() -> Any:
    return typer.Option([], "--task-opt", metavar="KEY=VALUE", help="A task option (repeatable; VALUE read as JSON "
                        "where it parses), e.g. pick's colours=3: three coloured cubes, the target named by each "
                        "episode's instruction.", show_default="the task's defaults")


def target_options(env: str | None, env_opt: list[str], task_opt: list[str], blocks: int | None) -> dict[str, Any]:
    """The options of what a command runs: an environment's (``--env-opt``), else the task's (``--blocks``,
    ``--task-opt``)."""
    if task_opt and env is not None:
        raise DemoError("--task-opt", "sets an option of --task; an environment's are --env-opt")
    if env is not None:
        return parse_env_opts(env_opt)
    return {**({} if blocks is None else {"blocks": blocks}), **parse_env_opts(task_opt, "--task-opt")}


def parse_env_opts(items: list[str], flag: str = "--env-opt") -> dict[str, Any]:
    """``--env-opt KEY=VALUE`` items as keyword arguments (a value that parses as JSON is that value)."""
    opts: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise DemoError(flag, f"{item!r} is not KEY=VALUE (e.g. max_episode_steps=200)")
        try:
            opts[key.strip()] = json.loads(text)
        except json.JSONDecodeError:
            opts[key.strip()] = text
    return opts
