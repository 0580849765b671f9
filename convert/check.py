"""How much a conversion changes what the robot does, measured two ways.

* :func:`replay_check` (``demo convert --check``): for each episode, restore the recorded state of
  frame 0 (``sim.state``), execute the original actions, restore it again and execute the converted
  actions through :class:`demo.convert.adapter.ActionAdapter` (IK each step for EE actions, as a
  policy would run), then compare the two rollouts' *measured* EE poses after every step (max
  position error in m, max rotation error in rad) and the task success at the end of each rollout.
* :func:`round_trip` (``demo convert --round-trip``): source -> target -> source -> target in
  memory, and the commanded EE poses of the first and the last source actions compared (max
  position/rotation error on frames where IK converged, and the converged share). No simulation.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demo.convert import representations as reps
from demo.convert.adapter import ActionAdapter
from demo.convert.context import load_context
from demo.convert.convert import ConvertOptions, Converter, IKSummary, episode_anchors, measured_joints, target_format
from demo.convert.representations import ActionFormat, JointTrack, PoseTrack, Segments
from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.sim import make_env
from demo.sim.geometry import angle_between, quat_to_mat
from demo.store import EpisodeStore
from demo.store.location import store_path


@dataclass
class EpisodeCheck:
    episode: int
    frames: int
    max_pos_err_m: float
    max_rot_err_rad: float
    recorded_success: bool
    original_success: bool
    converted_success: bool
    ik_failed_steps: int

    @property
    def agree(self) -> bool:
        return self.original_success == self.converted_success


@dataclass
class CheckReport:
    path: str
    source: str
    target: str
    episodes: list[EpisodeCheck] = field(default_factory=list)
    replayed_from: str = "recorded states"  # where each replay starts (a Gymnasium environment's: its seed)

    def summary(self) -> dict[str, Any]:
        eps = self.episodes
        orig = [e for e in eps if e.original_success]
        kept = sum(e.converted_success for e in orig)
        return {
            "episodes": len(eps),
            "max_pos_err_m": max((e.max_pos_err_m for e in eps), default=0.0),
            "max_rot_err_rad": max((e.max_rot_err_rad for e in eps), default=0.0),
            "median_max_pos_err_m": float(np.median([e.max_pos_err_m for e in eps])) if eps else 0.0,
            "original_successes": len(orig),
            "converted_successes": sum(e.converted_success for e in eps),
            "converted_success_given_original": kept / len(orig) if orig else None,
            "success_agreement": sum(e.agree for e in eps) / len(eps) if eps else None,
            "ik_failed_steps": sum(e.ik_failed_steps for e in eps),
        }

    def to_json(self) -> dict[str, Any]:
        return {"path": self.path, "source": self.source, "target": self.target, "summary": self.summary(),
                "episodes": [{**asdict(e), "agree": e.agree} for e in self.episodes]}


def _rollout(env: Any, state0: np.ndarray, adapter: ActionAdapter, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Measured EE poses after each step ([T, 3], [T, 3, 3]) and the final success."""
    env.set_state(state0)
    adapter.reset(env)
    pos = np.empty((len(actions), 3))
    quat = np.empty((len(actions), 4))
    for t, a in enumerate(actions):
        env.step(adapter(a))
        pos[t], quat[t] = env.ee_pose()
    return pos, quat_to_mat(quat), bool(env.success())


def replay_check(
    path: str | Path,
    opts: ConvertOptions,
    *,
    episodes: Any = None,
    progress: Progress | None = None,
) -> CheckReport:
    """Replay original and converted actions of the selected episodes from their recorded states.

    ``progress`` counts episodes replayed (stage ``replay check``) and how many agree on success.
    """
    path = store_path(path)
    tell = or_silent(progress)
    with EpisodeStore.open(path) as store:
        meta = store.meta
        if "sim.state" not in meta.features:
            raise DemoError(path, "has no sim.state; --check replays episodes from their recorded states")
        ctx = load_context(meta, path, opts.robot, "--check")
        if ctx.scene is None:
            raise DemoError(path, f"its task {(meta.task or {}).get('name')!r} is not a demo.sim task; cannot replay")
        src = reps.parse_spec(meta.action, path / "zarr.json", ctx.robot.arm_joints)
        dst = target_format(opts, ctx, src)
        conv = Converter(src, dst, meta.fps, ctx, opts.ik)
        task = meta.task or {}
        env = make_env(task["name"], robot=ctx.robot, **dict(task.get("options") or {}))
        report = CheckReport(str(path), src.name, dst.name)
        chosen = store.select(episodes)
        try:
            run_src = ActionAdapter(src, env, kin=ctx.kin)
            run_dst = ActionAdapter(dst, env, opts.ik, kin=ctx.kin)
            tell(Tick("replay check", 0, len(chosen)))
            for i in chosen:
                ep = store.read_episode(int(i))
                seg = Segments.single(len(ep["action"]))
                anchor, _ = episode_anchors([ep], ctx, src, f"{path} episode {i}")
                q_measured = measured_joints(ep, ctx, f"{path} episode {i}")[0] if conv.needs_ik else None
                converted, _ = conv.convert(ep["action"], anchor, seg, f"{path} episode {i}", q_measured)
                converted = converted.astype(np.float32)  # as a store would hold it
                state0 = ep["sim.state"][0]
                p1, R1, ok1 = _rollout(env, state0, run_src, ep["action"])
                failures = run_dst.ik_failures
                p2, R2, ok2 = _rollout(env, state0, run_dst, converted)
                check = EpisodeCheck(
                    episode=int(i), frames=len(converted),
                    max_pos_err_m=float(np.linalg.norm(p1 - p2, axis=1).max()),
                    max_rot_err_rad=float(angle_between(R1, R2).max()),
                    recorded_success=bool(store.episode_info(int(i))["success"]),
                    original_success=ok1, converted_success=ok2,
                    ik_failed_steps=run_dst.ik_failures - failures,
                )
                report.episodes.append(check)
                agree = sum(e.agree for e in report.episodes)
                tell(Tick("replay check", len(report.episodes), len(chosen), {"agree": f"{agree}/{len(report.episodes)}"}))
        finally:
            env.close()
    return report


@dataclass
class RoundTrip:
    """Errors of source -> target -> source -> target (commanded EE poses, base frame)."""

    path: str
    source: str
    target: str
    frames: int
    ik: dict[str, Any]
    max_pos_err_m: float  # commanded EE pose of the last vs the first source actions, IK-converged frames
    max_rot_err_rad: float
    max_target_diff: list[float]  # per dimension: |target'' - target| over converged frames
    fk_vs_mujoco: dict[str, float]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def round_trip(path: str | Path, opts: ConvertOptions, *, episodes: Any = None,
               progress: Progress | None = None) -> RoundTrip:
    """Convert the selected episodes there and back twice, in memory, and measure what changed.

    ``progress`` counts episodes (stage ``round trip``).
    """
    path = store_path(path)
    tell = or_silent(progress)
    with EpisodeStore.open(path) as store:
        meta = store.meta
        ctx = load_context(meta, path, opts.robot, "--round-trip")
        src = reps.parse_spec(meta.action, path / "zarr.json", ctx.robot.arm_joints)
        dst = target_format(opts, ctx, src)
        if src.rep.space == dst.rep.space:
            raise DemoError("--round-trip", f"{src.name} and {dst.name} are both {src.rep.space} representations; "
                                            "the round trip measures the FK/IK crossing")
        there = Converter(src, dst, meta.fps, ctx, opts.ik)
        back = Converter(dst, src, meta.fps, ctx, opts.ik)
        ik = IKSummary()
        pos_err = rot_err = 0.0
        diff = np.zeros(dst.dim)
        frames = 0
        q_all = []
        chosen = store.select(episodes)
        tell(Tick("round trip", 0, len(chosen)))
        for done, i in enumerate(chosen, 1):
            ep = store.read_episode(int(i), ["action", *[k for k in ("sim.state", "obs.joint_pos",
                                                                       reps.EE_ANCHOR_KEY, reps.JOINT_ANCHOR_KEY)
                                                          if k in meta.features]])
            seg = Segments.single(len(ep["action"]))
            where = f"{path} episode {i}"
            anchor, _ = episode_anchors([ep], ctx, src, where)
            a0 = ep["action"]
            q_measured, _ = measured_joints(ep, ctx, where)  # the IK's warm starts
            b1, ik1 = there.convert(a0, anchor, seg, where, q_measured)
            b1 = b1.astype(np.float32)  # every stage as a store would hold it
            a2, ik2 = back.convert(b1, anchor, seg, where, q_measured)
            a2 = a2.astype(np.float32)
            b3, _ = there.convert(a2, anchor, seg, where, q_measured)
            results = (ik1 or []) + (ik2 or [])
            ok = np.ones(len(a0), bool)
            for r in results:
                ik.add(int(i), r)
                ok &= r.converged
            p0, R0 = _poses(there, src, a0, anchor, seg, where)
            p2, R2 = _poses(there, src, a2, anchor, seg, where)
            if ok.any():
                pos_err = max(pos_err, float(np.linalg.norm(p2 - p0, axis=1)[ok].max()))
                rot_err = max(rot_err, float(angle_between(R2, R0)[ok].max()))
                diff = np.maximum(diff, np.abs(b3 - b1)[ok].max(axis=0))
            frames += len(a0)
            if src.rep.space == "joint":
                q_all.append(there.commands(a0, anchor, seg, where).q)  # type: ignore[union-attr]
            tell(Tick("round trip", done, len(chosen)))
        q = np.concatenate(q_all) if q_all else ctx.kin.random_q(256, np.random.default_rng(0))
        pe, re = ctx.kin.verify(q[:: max(1, len(q) // 1000)])
    return RoundTrip(str(path), src.name, dst.name, frames, ik.to_json(), pos_err, rot_err, diff.tolist(),
                     {"max_pos_err_m": pe, "max_rot_err_rad": re})


def _poses(conv: Converter, fmt: ActionFormat, action: np.ndarray, anchor: Any, seg: Segments,
           where: object) -> tuple[np.ndarray, np.ndarray]:
    """Commanded EE poses of ``action`` in ``fmt`` (FK for joint formats)."""
    track = reps.decode(fmt, action, conv.fps, anchor, seg, where)
    if isinstance(track, JointTrack):
        return conv.fk(track.q)
    assert isinstance(track, PoseTrack)
    return track.pos, track.rot
