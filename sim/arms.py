"""Robots of several arms: a TOML that lists its arms, each an arm config of :mod:`demo.sim.robot`.

::

    name = "aloha_vx300s"
    [[arms]]
    name = "left"                       # how the arm is named in actions and reports
    config = "aloha_vx300s_left.toml"   # an arm config file, relative to this one ...
    [[arms]]
    name = "right"
    mjcf = "..."                        # ... or the arm config's keys written here
    arm_prefix = "vx300s_right/"
    ...

The arms may come from one MJCF (gym-aloha's two ViperX 300s: each arm config names its arm with
``arm_prefix``) or from several files, each with its own base pose. A robot's actions and observations
are its arms' concatenated in the listed order, each arm's joints (rad) then its gripper
(``<arm>.<joint>``, ``<arm>.gripper``): for gym-aloha's pair, left then right, gym-aloha's own 14-D order.
``demo robot check`` checks each arm as it checks a single arm. Arms that share a name, a joint, an
actuator or a body are refused in one line.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.sim.robot import RobotConfig, load_robot, read_robot_toml, robot_from_keys

# The observation that holds the arms' measured joints (rad) and grippers, laid out as the action (gym-aloha's
# ``agent_pos``, each gripper in the environment's command units)
MEASURED_KEY = "obs.agent_pos"


@dataclass(frozen=True)
class ArmsConfig:
    """A robot of several arms: each arm's name and its validated config, in action order."""

    name: str
    arm_names: tuple[str, ...]
    arms: tuple[RobotConfig, ...]
    config_path: Path

    @property
    def action_names(self) -> list[str]:
        """Every action (and proprioception) dimension's name, in order."""
        return [f"{name}.{part}" for name, arm in zip(self.arm_names, self.arms)
                for part in (*(j.removeprefix(arm.arm_prefix) for j in arm.arm_joints), "gripper")]

    def joint_dims(self) -> np.ndarray:
        """Indices of the arm joints' dimensions in the action (the grippers' left out), arm after arm."""
        return np.array([i for i, n in enumerate(self.action_names) if not n.endswith(".gripper")])

    def gripper_dims(self) -> np.ndarray:
        """Indices of the grippers' dimensions in the action, arm after arm."""
        return np.array([i for i, n in enumerate(self.action_names) if n.endswith(".gripper")])

    def arm_slices(self) -> list[slice]:
        """Each arm's dimensions in the action: its joints, then its gripper."""
        out, start = [], 0
        for arm in self.arms:
            out.append(slice(start, start + arm.n_arm + 1))
            start += arm.n_arm + 1
        return out

    def check_env(self, env: Any, where: str) -> tuple[float, float]:
        """That a Gymnasium environment (:class:`demo.sim.foreign.ForeignEnv`) takes these arms' joint targets:
        its action named as :attr:`action_names` says, and its gripper command at (open, closed), returned
        (``gripper_command``: gym-aloha's normalised opening is (1, 0)); a one-line error otherwise."""
        names = list(env.action_spec.names)
        if names != list(self.action_names):
            raise DemoError(where, f"its action is {_few(names)}; {self.name}'s arms take {_few(self.action_names)}")
        command = getattr(env.gym.unwrapped, "gripper_command", None)
        if command is None or len(command) != 2 or command[0] == command[1]:
            raise DemoError(where, "does not say its gripper command at open and at closed (gripper_command)")
        return float(command[0]), float(command[1])


def gripper_from_closedness(closedness: np.ndarray | float, gripper_command: tuple[float, float]) -> np.ndarray:
    """A gripper's closedness (0 open .. 1 closed) as the environment's command, given the command at (open, closed)
    (:meth:`ArmsConfig.check_env`)."""
    open_, closed = gripper_command
    return open_ + np.asarray(closedness) * (closed - open_)


def closedness_from_gripper(command: np.ndarray | float, gripper_command: tuple[float, float]) -> np.ndarray:
    """The inverse of :func:`gripper_from_closedness`: the environment's gripper command as closedness (0 open ..
    1 closed, unclipped)."""
    open_, closed = gripper_command
    return (np.asarray(command) - open_) / (closed - open_)


def _few(names: list[str]) -> str:
    return ", ".join(names) if len(names) <= 4 else f"{', '.join(names[:4])}, ... ({len(names)} dimensions)"


def lists_arms(path: str | Path) -> bool:
    """Whether the TOML file ``path`` is a robot of several arms (it has ``[[arms]]``)."""
    try:
        return "arms" in tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return False


def load_arms(path: str | Path) -> ArmsConfig:
    """Read and validate a robot of several arms (module docstring); every problem is one line naming the file."""
    where = Path(path).expanduser().resolve()
    raw = read_robot_toml(where)
    unknown = sorted(set(raw) - {"name", "arms"})
    if unknown:
        raise DemoError(where, f"a robot of several arms has 'name' and [[arms]] only, not {', '.join(unknown)}")
    tables = raw.get("arms")
    if not isinstance(tables, list) or len(tables) < 2 or not all(isinstance(t, dict) for t in tables):
        raise DemoError(where, "[[arms]] lists two or more arms, each a table")
    names, arms = [], []
    for i, table in enumerate(tables):
        name = table.get("name")
        if not isinstance(name, str) or not name.isidentifier():
            raise DemoError(where, f"arm {i + 1} needs a 'name' (a word, e.g. left)")
        names.append(name)
        arms.append(_arm(where, name, {k: v for k, v in table.items() if k != "name"}))
    _refuse_overlaps(where, names, arms)
    return ArmsConfig(str(raw.get("name", where.stem)), tuple(names), tuple(arms), where)


def _arm(where: Path, name: str, keys: dict[str, Any]) -> RobotConfig:
    if "config" in keys:
        if set(keys) != {"config"}:
            raise DemoError(where, f"arm {name!r}: 'config' names an arm config file; its keys go there, not beside it")
        arm_file = (where.parent / str(keys["config"])).resolve()
        if lists_arms(arm_file):
            raise DemoError(where, f"arm {name!r}: {arm_file.name} lists arms itself; an arm is one arm's config")
        return load_robot(arm_file)
    try:
        return robot_from_keys(keys, where.parent, where, default_name=name)
    except DemoError as exc:
        raise DemoError(where, f"arm {name!r}: {exc.problem}") from None


def _refuse_overlaps(where: Path, names: list[str], arms: list[RobotConfig]) -> None:
    """Two arms naming the same thing would drive (or report) one part twice."""
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise DemoError(where, f"two arms are named {repeated[0]!r}")
    for kind, parts in (("joint", lambda a: a.arm_joints), ("gripper actuator", lambda a: tuple(g for g, _ in a.grippers)),
                        ("base body", lambda a: (a.base_body,)),
                        ("EE site body", lambda a: (a.ee_site_body,) if a.ee_site_body else ())):
        seen: dict[str, str] = {}
        for name, arm in zip(names, arms):
            for part in parts(arm):
                if part in seen and (arm.mjcf_path == arms[names.index(seen[part])].mjcf_path):
                    raise DemoError(where, f"arms {seen[part]!r} and {name!r} share the {kind} {part!r} of "
                                           f"{arm.mjcf_path.name}: give each arm its own (arm_prefix)")
                seen.setdefault(part, name)
