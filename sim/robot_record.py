"""How a store (or a run) records its robot, and how that record becomes a robot again anywhere.

The record lives in ``meta.robot`` (a run copies it to ``run.json["robot"]``). The built-in arm,
which ships with the package, is ``{"name": "panda_prim", "config": "builtin"}``. Any other robot
is recorded **by content**::

    {"name": "my_arm",
     "config": "/abs/path/my_arm.toml",     # the TOML it was read from (informative only)
     "toml": {"mjcf": "my_arm.xml", ...},   # every config key; mjcf (and gripper_mjcf) relative to the files' folder
     "files": {"my_arm.xml": "<sha256>", "meshes/base.stl": "<sha256>", ...},
     "source": "/abs/path"}                 # the folder those files were read from

and the files themselves (the MJCF, its includes, meshes, textures, ..., and a separate gripper
MJCF's) are copied into the
store's (the run's) ``robot/`` folder, in their relative layout (see :mod:`demo.store.robot_files`).

:func:`resolve_robot` turns a record back into a :class:`RobotConfig`: a user's ``--robot`` wins;
else the files in ``<store or run>/robot/``; else the recorded ``source`` folder if it still holds
the same files (same sha256); else one DemoError naming the missing file and ``--robot``. Records
written before robots were recorded by content (``"config": "/abs/path.toml"`` only) still resolve
while that path exists.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from demo.errors import DemoError
from demo.sim.mjcf_files import mjcf_files
from demo.sim.robot import BUILTIN_CONFIG, RobotConfig, config_keys, load_robot, robot_from_keys
from demo.store.robot_files import ROBOT_DIR, file_table, locate, sha256_file

BUILTIN = "builtin"
HINT = "pass --robot ROBOT.toml to point at the robot's config"


def robot_record(robot: RobotConfig) -> dict[str, Any]:
    """The ``meta.robot`` record of ``robot``: ``builtin``, or its config and files by content."""
    if robot.config_path is not None and robot.config_path == BUILTIN_CONFIG.resolve():
        return {"name": robot.name, "config": BUILTIN}
    files = mjcf_files(robot.mjcf_path)
    gripper = mjcf_files(robot.gripper_mjcf) if robot.gripper_mjcf is not None else []
    files = list(dict.fromkeys(files + gripper))
    root = Path(os.path.commonpath([f.parent for f in files]))
    names = {f: f.relative_to(root).as_posix() for f in files}
    return {
        "name": robot.name,
        "config": str(robot.config_path) if robot.config_path else None,
        "toml": config_keys(robot, names[files[0]], names[gripper[0]] if gripper else None),
        "files": {names[f]: sha256_file(f) for f in files},
        "source": str(root),
    }


def resolve_robot(
    record: dict[str, Any] | None, override: str | Path | None = None, where: str | Path | None = None
) -> RobotConfig:
    """The robot a store's or run's ``record`` names, as ``demo.sim.make_env(robot=...)`` takes it.

    ``override``: a robot config the user named (``--robot``), used as is. ``where``: the store or
    run directory the record belongs to (its ``robot/`` folder holds the files). Raises a one-line
    DemoError naming the missing (or changed) file and how to point at the robot.
    """
    if override is not None:
        return load_robot(override)
    record = record or {}
    config = record.get("config")
    if config == BUILTIN:
        return load_robot(None)
    files = file_table(record, where)
    if files:
        folder, problem = locate(record, where)
        if folder is None:
            path, what = problem  # type: ignore[misc]
            source = record.get("source")
            elsewhere = f", and the recorded source folder {source} does not hold the same files" if source else ""
            raise DemoError(path, f"{what} (robot {record.get('name')!r}){elsewhere}; {HINT}")
        return _from_folder(record, files, folder, where)
    if isinstance(config, str) and config:
        if not Path(config).is_file():
            raise DemoError(config, f"robot config not found (robot {record.get('name')!r} of {where}); {HINT}")
        return load_robot(config)
    raise DemoError(where, f"records no robot config (robot {record.get('name', 'unnamed')!r}); {HINT}")


def _from_folder(record: dict[str, Any], files: dict[str, str], folder: Path, where: str | Path | None) -> RobotConfig:
    """Build the recorded config on the files in ``folder``; a store's own copy may not lead outside it."""
    keys = record.get("toml")
    if not isinstance(keys, dict) or keys.get("mjcf") not in files:
        raise DemoError(where, "robot record's 'toml' names no MJCF among its recorded files")
    if "gripper_mjcf" in keys and keys["gripper_mjcf"] not in files:
        raise DemoError(where, "robot record's 'gripper_mjcf' is not among its recorded files")
    if where is not None and folder == Path(where) / ROBOT_DIR:  # the store's own copy: nothing may lead out
        for key in ("mjcf", "gripper_mjcf"):
            if key in keys:
                mjcf_files(folder / keys[key], within=folder)
    return robot_from_keys(keys, folder, folder, default_name=str(record.get("name", "robot")))


def describe_robot(record: dict[str, Any] | None, where: str | Path | None) -> tuple[str, DemoError | None]:
    """``(one line for `demo info`, the error resolving it or None)``: the robot and where it comes from.

    A record that names no config (e.g. an imported dataset) is not an error: there is nothing to find.
    """
    record = record or {}
    name = record.get("name", "-")
    if not record.get("config") and not record.get("files"):
        return f"{name} (no robot config recorded)", None
    try:
        robot = resolve_robot(record, where=where)
    except DemoError as exc:
        return f"{name}: {exc}", exc
    if record.get("config") == BUILTIN:
        return f"{name} (built-in)", None
    n = len(record.get("files") or {})
    own = where is not None and robot.config_path == Path(where) / ROBOT_DIR
    origin = "files stored with it" if own else f"from {robot.config_path}"
    return f"{name} ({origin}{f', {n} files, sha256 verified' if n else ''})", None
