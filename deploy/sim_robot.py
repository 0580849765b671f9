"""The simulator as a stand-in robot: a separate process stepping physics in real time.

The process owns a :class:`demo.sim.env.Env` and runs it at the control rate on the wall clock: each
tick it takes the newest command it has been sent (holding the last one if none came: a robot's
zero-order hold), steps the physics one control step, and publishes the observation with the time it
was taken. It does not wait for anyone: a client that is late simply has its older command executed
again, as on a robot. Success is judged by the task's own predicate, held as ``demo eval`` holds it.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from typing import Any

import numpy as np

from demo.sim.rollout import HOLD_SUCCESS_S, SuccessHold


def _robot_process(conn: Any, task: str, env_kwargs: dict[str, Any], rate_hz: float) -> None:
    from demo.sim import make_env  # in the child: its own MuJoCo

    env = make_env(task, **env_kwargs)
    period = 1.0 / rate_hz
    while True:
        message = conn.recv()
        if message[0] == "close":
            break
        if message[0] != "episode":
            continue  # a command that arrived after the last episode ended
        seed = int(message[1])
        obs = env.reset(seed)
        hold = SuccessHold(HOLD_SUCCESS_S, env.fps)
        command = np.r_[obs["obs.joint_pos"], env.robot.home_gripper].astype(np.float64)
        conn.send(("obs", 0, time.time(), obs, False, False))
        t_next = time.perf_counter() + period
        for step in range(1, env.horizon + 1):
            while conn.poll():  # the newest command wins
                kind, *rest = conn.recv()
                if kind == "command":
                    command = np.asarray(rest[0], dtype=np.float64)
                elif kind == "stop":
                    break
            obs, _, success, truncated, _ = env.step(command)
            done = hold.update(bool(success)) or truncated
            conn.send(("obs", step, time.time(), obs, bool(done and success), bool(done)))
            if done:
                break
            delay = t_next - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            t_next += period
        conn.send(("end",))
    env.close()


class SimRobot:
    """The robot side of the loop in another process; :meth:`episode` starts one, :meth:`latest` gives the
    newest observation, :meth:`send` a command (``joint_pos``: arm targets in rad + gripper closedness)."""

    def __init__(self, task: str, rate_hz: float = 20.0, **env_kwargs: Any):
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_robot_process, args=(child, task, env_kwargs, rate_hz), daemon=True)
        self.process.start()
        self.latest_obs: tuple[int, float, dict[str, np.ndarray]] | None = None
        self.success = False
        self.done = False
        self.ended = True

    def episode(self, seed: int) -> None:
        if not self.ended:
            self.finish()
        self.latest_obs, self.success, self.done, self.ended = None, False, False, False
        self.conn.send(("episode", seed))
        self.poll(block=True)

    def poll(self, block: bool = False) -> None:
        """Take in what the robot published (``block``: wait for one message first)."""
        while (block and self.latest_obs is None) or self.conn.poll():
            message = self.conn.recv()
            if message[0] == "end":
                self.done = self.ended = True
                return
            _, step, t_obs, obs, success, done = message
            self.latest_obs = (step, t_obs, obs)
            self.success, self.done = self.success or success, self.done or done
            block = False

    def send(self, command: np.ndarray) -> None:
        self.conn.send(("command", np.asarray(command, dtype=np.float64)))

    def finish(self) -> None:
        """Wait for the episode's end (after ``done``: the robot's last messages)."""
        while not self.ended:
            self.latest_obs = None
            self.poll(block=True)

    def close(self) -> None:
        try:
            self.conn.send(("close",))
        except (BrokenPipeError, OSError):
            pass
        self.process.join(timeout=10)
