"""`demo bench retarget`: VR-style retargeting speed, poses/s on one core, against the bare IK solve.

Figure: control-rate hand poses retargeted per second by the whole pipeline of ``collect_vr``
(One Euro smoothing and resampling of the tracker stream, clutch/scaling map, ``iters`` IK
iterations with every limit, the reachability check by forward kinematics), without physics.
The stream is a hand drawing loops in front of the robot at 60 Hz, 2 mm of jitter.

Reference, same run: the bare solve (one IK iteration: load the configuration + ``solve_ik`` with
explicit limits for mink, ``solve`` for placo) on the same robot. Target: >= 200 poses/s (VR
streams at 30-90 Hz). The process is pinned to one CPU while it measures.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from demo.bench.common import machine, one_core, rate
from demo.collect.human import InputEpisode
from demo.collect.retarget import IK_BACKENDS, Retargeter, RetargetParams
from demo.collect.vr import HandMapper, HandRetargeter, PoseTrack, resample, smooth
from demo.sim import make_env

TARGET_POSES_PER_S = 200.0


def loop_track(env: Any, seconds: float = 4.0, rate_hz: float = 60.0, seed: int = 0) -> PoseTrack:
    """A hand drawing horizontal loops (radius 8 cm, 0.5 Hz) around the EE's reset pose, base frame."""
    rng = np.random.default_rng(seed)
    pos0, quat0 = env.ee_pose()
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    phase = 2 * np.pi * 0.5 * t
    pos = pos0 + np.stack([0.08 * np.sin(phase), 0.08 * (1 - np.cos(phase)), -0.03 * np.sin(2 * phase)], axis=1)
    pos += rng.normal(0.0, 0.002, pos.shape)
    quat = np.tile(quat0, (len(t), 1))
    return PoseTrack(InputEpisode(1, None, None), t, pos, quat, np.zeros(len(t)), np.ones(len(t), dtype=bool))


def measure_backend(env: Any, ik: str, track: PoseTrack, seconds: float) -> dict[str, Any]:
    params = RetargetParams()
    env.reset(0)
    q0 = env.data.qpos[env.arm_qadr].copy()
    hand = HandRetargeter(HandMapper(None, 1.0), Retargeter(env, ik, params))
    steps = resample(smooth(track), env.fps)
    n = len(steps)
    flags: list[bool] = []

    def pipeline() -> None:
        stream = resample(smooth(track), env.fps)
        hand.reset(q0)
        flags.clear()
        for k in range(n):
            step, _ = hand(stream.pos[k], stream.quat[k], bool(stream.engaged[k]))
            flags.append(step.ok)

    poses = rate(pipeline, n, seconds)
    backend = hand.retargeter.backend
    pos_w = env.to_world(track.pos[len(track.t) // 3])
    quat_w = env.quat_to_world(track.quat[0])
    bare = rate(lambda: backend.iterate(q0, pos_w, quat_w), 1, seconds / 2, warmup=5)
    return {
        "ik": ik,
        "poses_per_s": poses["per_s"],
        "poses_per_s_best_slice": poses["best_slice_per_s"],
        "ms_per_pose": 1e3 / poses["per_s"],
        "reference_bare_solves_per_s": bare["per_s"],
        "reference_ms_per_solve": 1e3 / bare["per_s"],
        "ik_iterations_per_pose": params.iters,
        "pose_cost_in_bare_solves": bare["per_s"] / poses["per_s"],
        "poses_reached": float(np.mean(flags)) if flags else float("nan"),
        "meets_target": bool(poses["per_s"] >= TARGET_POSES_PER_S),
    }


def run(task: str = "pick", seconds: float = 2.0, backends: tuple[str, ...] = IK_BACKENDS, seed: int = 0) -> dict[str, Any]:
    env = make_env(task)
    try:
        env.reset(seed)
        track = loop_track(env, seed=seed)
        with one_core() as cpu:
            results = {ik: measure_backend(env, ik, track, seconds) for ik in backends}
    finally:
        env.close()
    return {
        "benchmark": "retarget",
        "task": task,
        "stream": {"tracker_hz": 60.0, "control_hz": float(env.fps), "seconds": float(track.duration), "jitter_m": 0.002},
        "backends": results,
        "reference": "bare IK iteration (set configuration + solve) on the same robot and limits, same run",
        "target_poses_per_s": TARGET_POSES_PER_S,
        "meets_target": all(r["meets_target"] for r in results.values()),
        "pinned_cpu": cpu,
        "machine": machine(),
    }
