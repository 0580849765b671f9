"""The robot-side control loop: actions at the control rate from chunks computed elsewhere.

Inference runs in a thread (:class:`ChunkRequester`): it sends the newest observation, with the
control step it was taken at, whenever no request is in flight, and files the answer. The loop never
waits for it. Each control step executes the merge of every chunk that covers the step
(:class:`ChunkMerger`: a chunk answering the observation of step ``s`` holds actions for steps
``s .. s + H - 1``; overlapping ones are averaged with ACT's weights ``exp(-m * age)``, the oldest
heaviest), so a slow answer only means the older chunks carry on. The robot holds still until the episode's
first chunk arrives, and that chunk starts at the step it is first used (the state it answered is the state
the robot still holds): executed from ``s``, it would start ``d`` steps into a motion the robot never made,
and each later chunk would correct the last one's jump, late (``demo bench delay`` on ``pick``, state BC, a
6-step delay: 0/100 anchored at ``s``, 94/100 anchored at its arrival). For a policy trained to continue a committed
prefix (:mod:`demo.policies.prefix`), each request carries the merged actions already planned for the
steps until its answer is expected (the recent round trips, plus a step), and the answer continues them.
Then :class:`Safety`: joint
targets within the joint limits, at most ``max_joint_step`` rad from the last command per step,
the gripper within [0, 1], and the end effector at those targets inside the workspace box (scene
frame, m; else the arm holds its last command); no chunk covering the step, or an observation older
than ``stale_obs_s``, holds the last command (and counts a stall). ``synchronous``: the baseline a robot that waits for its
policy gets, each step's own chunk awaited before the step's merged action is sent.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from websockets.sync.client import connect

from demo.deploy.protocol import decode, encode, pack_array, unpack_array
from demo.errors import DemoError


@dataclass
class ControlConfig:
    rate_hz: float = 20.0
    ensemble: float = 0.01  # ACT's m: weight exp(-m * age) of an overlapping chunk's action
    max_joint_step: float = 0.1  # rad per control step (2 rad/s at 20 Hz)
    stale_obs_s: float = 0.25  # an observation older than this: hold
    network_s: float = 0.0  # injected one-way network delay (tests), each way
    # The baseline: each step waits for the chunk answering its own observation, then executes the merge
    # (the robot, which does not wait, holds the last command meanwhile).
    synchronous: bool = False


class ChunkMerger:
    """Chunks by the control step of the observation they answer."""

    def __init__(self, ensemble: float, anchor: bool = True):
        self.ensemble = ensemble
        # Whether an episode's first chunk starts at the step it is first used (module docstring); False: at the
        # step of the observation it answered, like every other (kept to measure the difference)
        self.anchor = anchor
        self.chunks: deque[tuple[int, np.ndarray]] = deque()
        self.lock = threading.Lock()
        self.anchored = not anchor  # whether the episode's first chunk has been used (and started then)

    def reset(self) -> None:
        """A new episode: no chunks; the first to come starts at the step it is first used."""
        with self.lock:
            self.chunks.clear()
            self.anchored = not self.anchor

    def add(self, start: int, chunk: np.ndarray) -> None:
        with self.lock:
            self.chunks.append((start, chunk))

    def action(self, t: int) -> np.ndarray | None:
        """The merged action to execute at step ``t``, or None when no chunk covers it."""
        with self.lock:
            if not self.anchored and self.chunks:  # the robot held still until now (module docstring)
                self.chunks[0] = (t, self.chunks[0][1])
                self.anchored = True
            self.chunks = deque((s, c) for s, c in self.chunks if s + len(c) > t)  # drop the spent ones
        return self.planned(t)

    def planned(self, t: int) -> np.ndarray | None:
        """The merged action the chunks filed so far give step ``t`` (now or ahead; nothing is dropped), or None
        where none covers it."""
        with self.lock:
            covering = [c[t - s] for s, c in self.chunks if s <= t < s + len(c)]
        if not covering:
            return None
        w = np.exp(-self.ensemble * np.arange(len(covering)))
        return (w[:, None] * np.stack(covering)).sum(axis=0) / w.sum()

    def committed(self, t: int, steps: int) -> np.ndarray | None:
        """``[d, A]``: the merged actions planned for steps ``t .. t + d - 1``, ``d <= steps`` up to the first step
        no chunk covers (the prefix a policy that continues one is told, :mod:`demo.policies.prefix`); None for none."""
        planned = []
        for k in range(steps):
            action = self.planned(t + k)
            if action is None:
                break
            planned.append(action)
        return np.asarray(planned) if planned else None


class ChunkRequester:
    """The inference thread: one request in flight at a time, the answers filed in ``merger``."""

    def __init__(self, url: str, merger: ChunkMerger, network_s: float = 0.0):
        try:
            self.ws = connect(url, max_size=2**26, open_timeout=10)
        except OSError as exc:
            raise DemoError(url, f"cannot connect to the policy server ({exc})") from None
        self.merger, self.network_s = merger, network_s
        self.pending: tuple[int, float, dict[str, np.ndarray], np.ndarray | None] | None = None
        self.prefix_steps = 0  # committed actions the served policy continues (the server says, at reset)
        self.wake = threading.Condition()
        self.busy = False
        self.latencies: list[float] = []  # s, observation sent -> chunk filed
        self.error: str | None = None
        self.closed = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def reset(self, seed: int) -> None:
        with self.wake:
            while self.busy:
                self.wake.wait()
            self.ws.send(encode({"type": "reset", "seed": int(seed)}))
            self.prefix_steps = int(decode(self.ws.recv()).get("prefix_steps", 0))

    def submit(self, step: int, t_obs: float, frame: dict[str, np.ndarray], prefix: np.ndarray | None = None) -> bool:
        """Ask for a chunk from this observation unless a request is in flight; whether it was sent. ``prefix``
        ``[d, A]``: the actions already committed for steps ``step .. step + d - 1``."""
        with self.wake:
            if self.busy:
                return False
            self.pending, self.busy = (step, t_obs, frame, prefix), True
            self.wake.notify_all()
            return True

    def wait(self) -> None:
        """Until no request is in flight."""
        with self.wake:
            while self.busy:
                self.wake.wait()

    def _run(self) -> None:
        while True:
            with self.wake:
                while self.pending is None and not self.closed:
                    self.wake.wait()
                if self.closed:
                    return
                step, t_obs, frame, prefix = self.pending
                self.pending = None
            sent = time.perf_counter()
            try:
                time.sleep(self.network_s)
                message = {"type": "obs", "seq": step, "t_obs": t_obs,
                           "frame": {k: pack_array(np.asarray(v)) for k, v in frame.items()}}
                if prefix is not None:
                    message["prefix"] = pack_array(np.asarray(prefix, np.float32))
                self.ws.send(encode(message))
                answer = decode(self.ws.recv())
                time.sleep(self.network_s)
                if answer["type"] == "error":
                    self.error = answer["problem"]
                else:
                    self.merger.add(int(answer["seq"]), unpack_array(answer["chunk"]).astype(np.float64))
                    self.latencies.append(time.perf_counter() - sent)
            except Exception as exc:  # noqa: BLE001 - the loop holds and reports; it must not die silently
                self.error = str(exc)
            with self.wake:
                self.busy = False
                self.wake.notify_all()

    def steps_ahead(self, period: float) -> int:
        """Control steps until an answer to a request sent now is expected: the slowest of the last few round
        trips, plus one step (the answer is used at the first tick after it is filed)."""
        recent = self.latencies[-5:]
        return int(np.ceil(max(recent) / period)) + 1 if recent else 0

    def close(self) -> None:
        with self.wake:
            self.closed = True
            self.wake.notify_all()
        self.ws.close()


@dataclass
class Safety:
    """Limits every command obeys (module docstring); ``limits`` [n_arm, 2] rad. ``workspace`` ([2, 3]: the
    lowest and highest corner, scene frame, m) with ``ee_position`` (arm joint targets -> the end effector's
    position there, the client's own kinematic model of the arm): a command that would take the end
    effector out of the box keeps the arm where the last command had it (the gripper still obeys)."""

    limits: np.ndarray
    max_joint_step: float
    workspace: np.ndarray | None = None
    ee_position: Callable[[np.ndarray], np.ndarray] | None = None
    clipped: int = 0  # commands these limits changed
    outside: int = 0  # ... of which held because of the workspace

    def __call__(self, action: np.ndarray, last: np.ndarray) -> np.ndarray:
        a = np.array(action, dtype=np.float64)
        n = len(self.limits)
        arm = np.clip(a[:n], self.limits[:, 0], self.limits[:, 1])
        arm = last[:n] + np.clip(arm - last[:n], -self.max_joint_step, self.max_joint_step)
        if self.workspace is not None and self.ee_position is not None:
            ee = self.ee_position(arm)
            if np.any(ee < self.workspace[0]) or np.any(ee > self.workspace[1]):
                arm = np.array(last[:n], dtype=np.float64)
                self.outside += 1
        grip = np.clip(a[n:], 0.0, 1.0)
        out = np.r_[arm, grip]
        self.clipped += int(not np.allclose(out, a))
        return out


@dataclass
class EpisodeReport:
    seed: int
    success: bool
    steps: int
    stalls: int  # control steps that held the last command (no chunk, or a stale observation)
    clipped: int  # commands the safety limits changed
    outside: int = 0  # ... held because the end effector would have left the workspace
    latency_ms: list[float] = field(default_factory=list)
    overruns: int = 0  # control steps the loop itself started late by more than a period


def run_episode(robot: Any, requester: ChunkRequester, safety: Safety, config: ControlConfig, seed: int) -> EpisodeReport:
    """One episode of ``robot`` (:class:`demo.deploy.sim_robot.SimRobot`) under the real-time loop."""
    merger = requester.merger
    requester.reset(seed)  # waits for an answer still in flight, then files nothing more of the last episode
    merger.reset()
    robot.episode(seed)
    period = 1.0 / config.rate_hz
    step, t_obs, obs = robot.latest_obs
    last = np.r_[obs["obs.joint_pos"], obs["obs.gripper"]].astype(np.float64)
    stalls = overruns = steps = 0
    safety.clipped = safety.outside = 0
    start_latencies = len(requester.latencies)
    t_next = time.perf_counter()
    while not robot.done:
        robot.poll()
        if robot.done:
            break
        step, t_obs, obs = robot.latest_obs
        if config.synchronous:
            requester.submit(step, t_obs, obs)
            requester.wait()
            action = merger.action(step)
        else:
            action = merger.action(step)  # the robot applies it to the state of ``step``, at its next tick
            prefix = None
            if requester.prefix_steps and not requester.busy:
                prefix = merger.committed(step, min(requester.prefix_steps, requester.steps_ahead(period)))
            requester.submit(step, t_obs, obs, prefix)
        if action is None or time.time() - t_obs > config.stale_obs_s:
            stalls += 1
            command = last
        else:
            command = safety(action, last)
        robot.send(command)
        last = command
        steps += 1
        t_next += period
        delay = t_next - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        elif -delay > period:
            overruns += 1
    robot.finish()
    if requester.error:
        raise DemoError("policy server", requester.error)
    return EpisodeReport(seed, robot.success, steps, stalls, safety.clipped, safety.outside,
                         [1000 * x for x in requester.latencies[start_latencies:]], overruns)
