"""`demo bench convert`: joint_pos -> ee7 conversion speed on one core, with its reference and peer.

All three are measured in the same run, pinned to one CPU core, over the same frames (synthetic
smooth joint trajectories of the robot within its joint limits, 150-frame episodes):

* ``joint_pos->ee7``: :class:`demo.convert.convert.Converter` on in-memory arrays (anchor FK,
  batched FK, deltas, Euler angles; no store I/O), best of 3 runs;
* ``mj_kinematics loop`` (reference): set the arm's ``qpos`` and call ``mujoco.mj_kinematics`` once
  per frame, nothing else (the floor of any per-frame MuJoCo FK);
* ``placo FK loop`` (peer): per frame ``set_joint`` for each arm joint, ``update_kinematics`` and
  ``get_T_world_frame(ee_site)``, the way LeRobot computes FK with placo.
"""

from __future__ import annotations

import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.bench.common import one_core
from demo.collect.ik_placo import quiet_stdout
from demo.convert import representations as reps
from demo.convert.context import RobotContext
from demo.convert.convert import Converter
from demo.convert.kinematics import Kinematics
from demo.convert.representations import Anchor, Segments
from demo.sim import load_robot

TARGET_FRAMES_PER_S = 100_000
EPISODE_LENGTH = 150


def synthetic_episodes(kin: Kinematics, frames: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, Segments]:
    """joint_pos actions [N, n+1], per-episode measured start q [E, n], and the episode segments."""
    lo = np.where(np.isfinite(kin.lower), kin.lower, -np.pi)
    hi = np.where(np.isfinite(kin.upper), kin.upper, np.pi)
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    n_ep = max(1, frames // EPISODE_LENGTH)
    lengths = np.full(n_ep, EPISODE_LENGTH)
    lengths[-1] += frames - lengths.sum()
    seg = Segments(np.cumsum(lengths))
    start = mid + rng.uniform(-0.6, 0.6, (n_ep, kin.n_arm)) * half
    steps = rng.normal(0.0, 0.02, (frames, kin.n_arm))  # ~0.4 rad/s at 20 Hz
    q = np.clip(np.repeat(start, seg.lengths, axis=0) + seg.cumsum(steps), lo, hi)
    grip = (rng.uniform(size=frames) > 0.5).astype(np.float64)
    action = np.concatenate([q, grip[:, None]], axis=1).astype(np.float32)
    return action, start, seg


def _best_of(fn: Any, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def run_bench(frames: int = 200_000, robot: str | None = None, placo_frames: int = 20_000, seed: int = 0) -> dict[str, Any]:
    """Run the three measurements; returns the JSON written by ``demo bench convert``."""
    rb = load_robot(robot)
    model = rb.spec().compile()
    kin = Kinematics(model, rb.arm_joints, rb.ee_site, rb.base_body, where=rb.config_path)
    action, start_q, seg = synthetic_episodes(kin, frames, np.random.default_rng(seed))
    src = reps.make_format("joint_pos", joint_names=rb.arm_joints)
    dst = reps.make_format("ee7")
    conv = Converter(src, dst, 20.0, RobotContext(rb, kin, None, None, None))

    def ours() -> np.ndarray:
        pos, rot = kin.fk(start_q)
        out, _ = conv.convert(action, Anchor(q=start_q, pos=pos, rot=rot), seg)
        return out

    q64 = action[:, :-1].astype(np.float64)
    data = mujoco.MjData(model)
    adr = kin.qpos_adr

    def mj_loop() -> None:
        m, d = model, data
        for i in range(len(q64)):
            d.qpos[adr] = q64[i]
            mujoco.mj_kinematics(m, d)

    results: dict[str, dict[str, Any]] = {}
    with one_core() as core:
        cpu = "unpinned (no sched_setaffinity)" if core is None else f"1 core (cpu {core})"
        ours()  # warm-up (allocations, caches)
        t_ours = _best_of(ours, 3)
        results["joint_pos->ee7"] = {"frames_per_s": frames / t_ours, "seconds": t_ours,
                                     "note": "batched numpy FK + deltas + Euler, best of 3"}
        t_mj = _best_of(mj_loop, 2)
        results["mj_kinematics loop"] = {"frames_per_s": frames / t_mj, "seconds": t_mj,
                                         "note": "reference: set qpos + mj_kinematics per frame, best of 2"}
        results["placo FK loop"] = _placo(rb, q64[:placo_frames], kin)
    pos_err, rot_err = kin.verify(q64[:: max(1, frames // 2000)])
    ours_fps = results["joint_pos->ee7"]["frames_per_s"]
    placo_fps = results["placo FK loop"].get("frames_per_s")
    return {
        "bench": "convert",
        "robot": rb.name,
        "frames": frames,
        "episode_length": EPISODE_LENGTH,
        "cpu": cpu,
        "machine": platform.machine(),
        "results": results,
        "ratio_vs_mj_kinematics": ours_fps / results["mj_kinematics loop"]["frames_per_s"],
        "ratio_vs_placo": ours_fps / placo_fps if placo_fps else None,
        "target_frames_per_s": TARGET_FRAMES_PER_S,
        "target_met": ours_fps >= TARGET_FRAMES_PER_S,
        "fk_vs_mujoco": {"max_pos_err_m": pos_err, "max_rot_err_rad": rot_err},
    }


def _placo(rb: Any, q: np.ndarray, kin: Kinematics) -> dict[str, Any]:
    """Per-frame placo FK, as LeRobot does it; also checks it agrees with ours."""
    import placo  # deferred: heavy dependency (placo), for this comparison alone
    spec = rb.spec()
    for key in list(spec.keys):  # pinocchio's MJCF reader rejects keyframes that include tendon-coupled joints
        spec.delete(key)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "robot.xml"
        path.write_text(spec.to_xml())
        try:
            with quiet_stdout():
                robot = placo.RobotWrapper(str(path), placo.Flags.mjcf | placo.Flags.ignore_collisions)
        except Exception as exc:
            return {"error": f"placo cannot load the robot: {str(exc).splitlines()[-1][:200]}"}
    names, site, base = list(rb.arm_joints), rb.ee_site, rb.base_body

    def loop() -> np.ndarray:
        out = np.empty((len(q), 3))
        for i in range(len(q)):
            for j, name in enumerate(names):
                robot.set_joint(name, q[i, j])
            robot.update_kinematics()
            out[i] = robot.get_T_world_frame(site)[:3, 3]
        return out

    t = time.perf_counter()
    pos = loop()
    seconds = time.perf_counter() - t
    tb = robot.get_T_world_frame(base)  # the base is fixed: one transform for every frame
    rel = (pos - tb[:3, 3]) @ tb[:3, :3]
    ours, _ = kin.fk(q)
    return {"frames_per_s": len(q) / seconds, "seconds": seconds, "frames": int(len(q)),
            "note": "peer: set_joint x n + update_kinematics + get_T_world_frame per frame",
            "max_pos_diff_vs_ours_m": float(np.abs(rel - ours).max(initial=0.0))}
