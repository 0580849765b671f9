"""``--env process:NAME --env-opt python=PYTHON``: a Gymnasium environment run by another Python interpreter.

A benchmark whose packages cannot live beside ``demo``'s runs in its own virtual environment (gym-aloha's
dm_control builds only on MuJoCo < 3.9, ``demo`` needs MuJoCo 4): :class:`ProcessEnv` is a
``gymnasium.Env`` whose ``reset`` and ``step`` go over a pipe to :mod:`demo.sim.env_worker`, a script that
interpreter runs with nothing of ``demo`` installed (numpy and gymnasium only). Observations, actions and
``info`` travel as ``.npy`` arrays in length-prefixed frames (no pickle either way), so everything
downstream (collection, training, ``demo eval``, the success flag) is the generic foreign-environment path
of :mod:`demo.sim.foreign`. ``NAME`` is what the worker builds: a Gymnasium id (``gym_aloha/AlohaTransferCube-v0``:
the ``gym_aloha`` module is imported first, which registers it), ``module:id`` or ``module:factory``; the
other ``--env-opt`` keys go to its constructor. The interpreter is part of the task options, so a store and
a run name it and ``demo eval RUN`` starts it again.

Each step costs a round trip through the pipe (encoding, two copies of the frame); an error in the
environment comes back as one line, and an interpreter that dies is named with the last line it printed.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from demo.errors import DemoError
from demo.sim import env_worker

PYTHON_OPTION = "python"
WORKER = Path(env_worker.__file__).resolve()
CLOSE_TIMEOUT_S = 5.0


def make(name: str, **options: Any) -> "ProcessEnv":
    """The adapter's factory (``--env process:NAME``): ``options`` hold ``python`` and the environment's own."""
    if PYTHON_OPTION not in options:
        raise DemoError(f"--env process:{name}", "names an environment run by another interpreter: give it with "
                                                 "--env-opt python=/path/to/venv/bin/python")
    python = str(options.pop(PYTHON_OPTION))
    return ProcessEnv(name, python, options)


class ProcessEnv(gymnasium.Env):
    """The environment ``name`` built with ``options`` in a worker process of the interpreter ``python``."""

    def __init__(self, name: str, python: str, options: dict[str, Any] | None = None):
        self.where = f"--env process:{name}"
        self.python = python
        path = Path(python).expanduser()
        if not path.is_file() or not os.access(path, os.X_OK):
            raise DemoError("--env-opt python", f"{python}: no such Python interpreter")
        self._stderr = tempfile.TemporaryFile()
        self._proc: subprocess.Popen | None = subprocess.Popen(
            [str(path), "-u", str(WORKER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr)
        try:
            made = self._call({"cmd": "make", "name": name, "options": dict(options or {})})
            self.observation_space = self._space(made["observation_space"])
            self.action_space = self._space(made["action_space"])
        except BaseException:
            self.close()
            raise
        self.metadata = {"render_fps": made["render_fps"]} if made.get("render_fps") else {}
        horizon = made.get("max_episode_steps") or made.get("horizon")
        if horizon:
            self.horizon = int(horizon)  # what demo.sim.foreign reads where the env has no spec
        if isinstance(made.get("instruction"), str):
            self.instruction = made["instruction"]
        # what the environment calls its action's dimensions, and its gripper command at open and closed
        for key in ("action_names", "action_units", "gripper_command"):
            if made.get(key) is not None:
                setattr(self, key, tuple(made[key]))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        reply = self._call({"cmd": "reset", "seed": seed})
        return reply["obs"], reply["info"]

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        reply = self._call({"cmd": "step", "action": np.asarray(action)})
        return reply["obs"], reply["reward"], reply["terminated"], reply["truncated"], reply["info"]

    def close(self) -> None:
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            if proc.poll() is None:
                env_worker.write_message(proc.stdin, {"cmd": "close"})
                proc.wait(timeout=CLOSE_TIMEOUT_S)
        except (OSError, ValueError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()
        finally:
            for stream in (proc.stdin, proc.stdout):
                if stream is not None:
                    # A dead worker's stdin may still hold what a failed write buffered: flushing it breaks the pipe.
                    with contextlib.suppress(OSError):
                        stream.close()
            self._stderr.close()

    # ------------------------------------------------------------------ the pipe
    def _call(self, message: dict[str, Any]) -> Any:
        proc = self._proc
        if proc is None:
            raise DemoError(self.where, "the environment is closed")
        try:
            env_worker.write_message(proc.stdin, message)
            reply = env_worker.read_message(proc.stdout)
        except (EOFError, OSError, ValueError) as exc:
            code = proc.wait()
            raise DemoError(self.where, f"its interpreter {self.python} ended (exit code {code}): "
                                        f"{self._last_words() or exc}") from None
        if "error" in reply:
            raise DemoError(self.where, str(reply["error"]))
        return reply["ok"]

    def _last_words(self) -> str:
        """The last non-empty line the worker wrote to stderr (a traceback's last line is its error)."""
        self._stderr.seek(0)
        lines = [line.strip() for line in self._stderr.read().decode(errors="replace").splitlines() if line.strip()]
        return lines[-1][:300] if lines else ""

    def _space(self, described: dict[str, Any]) -> gymnasium.Space:
        kind = described.get("type")
        if kind == "Box":
            return gymnasium.spaces.Box(low=described["low"], high=described["high"], dtype=np.dtype(described["dtype"]))
        if kind == "Dict":
            return gymnasium.spaces.Dict({k: self._space(v) for k, v in described["spaces"].items()})
        raise DemoError(self.where, f"has a {kind} space; a Box, or a Dict of them, is what demo reads")
