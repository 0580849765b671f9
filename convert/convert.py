"""`demo convert`: re-express a store's actions in another representation, into a new store.

The conversion goes through the commands the actions stand for (see
:mod:`demo.convert.representations`): decode the source actions into commanded joint targets or
commanded EE poses, cross between the two with batched forward kinematics (joint -> EE) or IK
(EE -> joint, :mod:`demo.convert.ik`), and encode them in the target representation. Episodes are
processed in blocks; within a block every step but IK is vectorised over all frames.

The new store keeps every other feature and per-episode column, replaces ``action``, adds the
target's anchor feature (``info.ee_anchor`` / ``info.joint_anchor``) when it is a delta
representation, and, when IK ran, ``info.ik_converged`` per frame plus the episode columns
``ik_failed_frames``, ``ik_max_pos_err`` (m) and ``ik_max_rot_err`` (rad). Its provenance records
the source, both action specs, the robot, the anchor source, the IK summary and an FK check against
MuJoCo's ``mj_kinematics``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demo.convert import representations as reps
from demo.convert.context import RobotContext, load_context
from demo.convert.ik import IKConfig, IKResult, IKSolver
from demo.convert.representations import (
    EE_ANCHOR_KEY, JOINT_ANCHOR_KEY, ActionFormat, Anchor, JointTrack, PoseTrack, Segments,
)
from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.sim.robot_record import robot_record
from demo.store import EpisodeStore, FeatureSpec, StoreMeta
from demo.store.location import StorePath, same_store, store_path

IK_KEY = "info.ik_converged"
BLOCK_FRAMES = 100_000  # frames converted (and committed) together
FK_CHECK_FRAMES = 256  # frames per conversion whose FK is recomputed by mj_kinematics
FK_CHECK_TOL = 1e-9  # m / rad: the numpy FK must agree with MuJoCo to this


@dataclass
class ConvertOptions:
    to: str
    rotation: str | None = None
    delta_frame: str | None = None
    robot: str | None = None  # robot config overriding the one the store names
    ik: IKConfig = field(default_factory=IKConfig)


@dataclass
class IKSummary:
    frames: int = 0
    converged: int = 0
    max_pos_err: float = 0.0  # m, over converged frames
    max_rot_err: float = 0.0  # rad, over converged frames
    mean_iters: float = 0.0
    failed: dict[int, list[int]] = field(default_factory=dict)  # episode -> frames that did not converge

    @property
    def converged_share(self) -> float:
        return self.converged / self.frames if self.frames else 1.0

    def add(self, episode: int, r: IKResult) -> None:
        n = len(r.converged)
        self.mean_iters = (self.mean_iters * self.frames + float(r.iters.sum())) / max(1, self.frames + n)
        self.frames += n
        self.converged += int(r.converged.sum())
        if r.converged.any():
            self.max_pos_err = max(self.max_pos_err, float(r.pos_err[r.converged].max()))
            self.max_rot_err = max(self.max_rot_err, float(r.rot_err[r.converged].max()))
        if not r.converged.all():
            self.failed[episode] = r.failed_frames.tolist()

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["converged_share"] = self.converged_share
        d["failed"] = {str(k): v for k, v in self.failed.items()}
        return d


@dataclass
class ConvertResult:
    path: str
    source: str
    target: str
    episodes: int
    frames: int
    seconds: float
    anchor_source: dict[str, int]
    ik: IKSummary | None
    fk_check: dict[str, float] | None

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["ik"] = self.ik.to_json() if self.ik else None
        return d


# ---------------------------------------------------------------------------------------------- core
class Converter:
    """Converts concatenated episodes from one :class:`ActionFormat` to another (no store I/O)."""

    def __init__(self, src: ActionFormat, dst: ActionFormat, fps: float, ctx: RobotContext | None,
                 ik_config: IKConfig | None = None):
        self.src, self.dst, self.fps, self.ctx = src, dst, float(fps), ctx
        self.crosses = src.rep.space != dst.rep.space
        if self.crosses and ctx is None:
            raise ValueError("converting between joint and EE representations needs a RobotContext")
        self._ik: IKSolver | None = None
        self._ik_config = ik_config or IKConfig()

    @property
    def ik(self) -> IKSolver:
        if self._ik is None:
            assert self.ctx is not None
            self._ik = IKSolver(self.ctx.kin, self._ik_config)
        return self._ik

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        assert self.ctx is not None
        return self.ctx.kin.fk(q)

    def commands(self, action: np.ndarray, anchor: Anchor | None, seg: Segments, where: object) -> JointTrack | PoseTrack:
        return reps.decode(self.src, action, self.fps, anchor, seg, where)

    @property
    def needs_ik(self) -> bool:
        return self.src.rep.space == "ee" and self.dst.rep.space == "joint"

    def convert(self, action: np.ndarray, anchor: Anchor | None, seg: Segments, where: object = "action",
                q_measured: np.ndarray | None = None) -> tuple[np.ndarray, list[IKResult] | None]:
        """Source actions [N, d] -> target actions [N, d'] (float64), and per-episode IK results.

        ``q_measured`` [N, n]: measured arm joints of every frame, the IK's warm starts (see
        :mod:`demo.convert.ik`); without it each frame starts from the previous solution.
        """
        track = self.commands(action, anchor, seg, where)
        ik_results = None
        if isinstance(track, JointTrack) and self.dst.rep.space == "ee":
            pos, rot = self.fk(track.q)
            track = PoseTrack(pos, rot, track.gripper)
        elif isinstance(track, PoseTrack) and self.dst.rep.space == "joint":
            track, ik_results = self.solve_ik(track, anchor, seg, q_measured)
        return reps.encode(self.dst, track, self.fps, anchor, seg, where), ik_results

    def solve_ik(self, track: PoseTrack, anchor: Anchor | None, seg: Segments,
                 q_measured: np.ndarray | None = None) -> tuple[JointTrack, list[IKResult]]:
        """IK per episode, warm-started from measured joints (else the anchor's, else the robot's home)."""
        assert self.ctx is not None
        q = np.empty((len(track.pos), self.ctx.kin.n_arm))
        results = []
        for e, (s, t) in enumerate(zip(seg.starts, seg.ends)):
            start = anchor.q[e] if anchor is not None and anchor.q is not None else self.ctx.home_q()
            warm = q_measured[s:t] if q_measured is not None else None
            r = self.ik.solve_track(track.pos[s:t], track.rot[s:t], start, warm)
            q[s:t] = r.q
            results.append(r)
        return JointTrack(q, track.gripper), results


def measured_joints(data: dict[str, np.ndarray], ctx: RobotContext | None, where: object) -> tuple[np.ndarray | None, str]:
    """Measured arm joints [M, n] of the frames in ``data`` (rows of ``sim.state``, else of
    ``obs.joint_pos``), and which key they came from; ``(None, "none")`` without either."""
    if ctx is None:
        return None, "none"
    if ctx.scene is not None and "sim.state" in data:
        return ctx.arm_q_from_states(data["sim.state"], where), "sim.state"
    joint_obs = data.get("obs.joint_pos")
    if joint_obs is not None and joint_obs.shape[1:] == (ctx.kin.n_arm,):
        return joint_obs.astype(np.float64), "obs.joint_pos"
    return None, "none"


def episode_anchors(episodes: list[dict[str, np.ndarray]], ctx: RobotContext | None, src: ActionFormat,
                    where: object) -> tuple[Anchor, str]:
    """The command before frame 0 of each episode (see representations), and where it came from.

    The anchor a delta source was encoded with wins (``info.ee_anchor`` / ``info.joint_anchor``), so
    decoding is exact; otherwise the measured state at frame 0 (``sim.state``, else
    ``obs.joint_pos``) with the EE pose by FK. With no measurement at all, an absolute source is
    anchored at its own first command (the first delta is then zero); the anchor is stored with
    the converted actions either way, so the way back stays exact.
    """
    first = {k: np.stack([ep[k][0] for ep in episodes]) for k in episodes[0]}
    anchor = Anchor()
    anchor.q, source = measured_joints(first, ctx, where)
    if JOINT_ANCHOR_KEY in first and (anchor.q is None or src.anchor_key == JOINT_ANCHOR_KEY):
        anchor.q, source = first[JOINT_ANCHOR_KEY].astype(np.float64), JOINT_ANCHOR_KEY
    if EE_ANCHOR_KEY in first and (anchor.q is None or src.anchor_key == EE_ANCHOR_KEY):
        pose = Anchor.from_pose7(first[EE_ANCHOR_KEY])
        anchor.pos, anchor.rot, source = pose.pos, pose.rot, EE_ANCHOR_KEY
    elif anchor.q is not None and ctx is not None:
        anchor.pos, anchor.rot = ctx.kin.fk(anchor.q)
    if anchor.q is None and anchor.pos is None and not src.rep.delta:
        lengths = [len(ep["action"]) for ep in episodes]
        seg = Segments(np.cumsum(lengths))
        track = reps.decode(src, np.concatenate([ep["action"] for ep in episodes]), 1.0, None, seg, where)
        if isinstance(track, JointTrack):
            anchor.q = track.q[seg.starts]
            if ctx is not None:
                anchor.pos, anchor.rot = ctx.kin.fk(anchor.q)
        else:
            anchor.pos, anchor.rot = track.pos[seg.starts], track.rot[seg.starts]
        source = "first_command"
    return anchor, source


def target_format(opts: ConvertOptions, ctx: RobotContext | None, src: ActionFormat | None = None,
                  where: object = "--to") -> ActionFormat:
    """The target format; joint names from the robot, else from a joint-space source."""
    names = ctx.robot.arm_joints if ctx else (src.joint_names if src else ())
    return reps.make_format(opts.to, joint_names=names, rotation=opts.rotation, delta_frame=opts.delta_frame,
                            where=where)


def fk_check(ctx: RobotContext, q: np.ndarray, rng: np.random.Generator) -> dict[str, float]:
    """Recompute the FK of a sample of frames with ``mj_kinematics``; fail loudly on disagreement."""
    pick = rng.choice(len(q), size=min(FK_CHECK_FRAMES, len(q)), replace=False) if len(q) else np.zeros(0, int)
    pe, re = ctx.kin.verify(q[pick])
    if pe > FK_CHECK_TOL or re > FK_CHECK_TOL:
        raise DemoError(ctx.robot.config_path, f"batched FK disagrees with MuJoCo's mj_kinematics by {pe:.2e} m / "
                                               f"{re:.2e} rad; this robot's kinematic chain is not supported")
    return {"frames": int(len(pick)), "max_pos_err_m": pe, "max_rot_err_rad": re}


# ---------------------------------------------------------------------------------------------- stores
def convert_store(
    src_path: str | Path,
    out: str | Path,
    opts: ConvertOptions,
    *,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> ConvertResult:
    """Write a copy of the store at ``src_path`` with actions in ``opts.to`` to ``out``.

    ``progress`` counts frames written (stage ``convert -> <to>``) once the output is created; the
    output appears at ``out``, replacing what is there, only when it is complete (nothing on failure).
    """
    started = time.perf_counter()
    report = or_silent(progress)
    src_path, out = store_path(src_path), store_path(out)
    with EpisodeStore.open(src_path) as store:
        if same_store(out, store.path):
            raise DemoError(out, "is the source store; write the conversion elsewhere")
        reps.get_representation(opts.to)
        meta = store.meta
        ctx = _context_for(meta, src_path, opts)
        src = reps.parse_spec(meta.action, src_path / "zarr.json", ctx.robot.arm_joints if ctx else ())
        dst = target_format(opts, ctx, src)
        if ctx is not None and dst.name == "joint_pos" and ctx.action_spec is not None:
            dst_spec = ctx.action_spec
        else:
            dst_spec = dst.spec()
        conv = Converter(src, dst, meta.fps, ctx, opts.ik)
        new_meta = _target_meta(meta, src, dst, dst_spec, conv.crosses and dst.rep.space == "joint")
        if opts.robot is not None and ctx is not None:  # the output records the robot it was converted with
            new_meta.robot = robot_record(ctx.robot)
        ik = IKSummary() if conv.crosses and dst.rep.space == "joint" else None
        anchor_sources: dict[str, int] = {}
        check: dict[str, float] | None = None
        skip = {"episode_index", "start", "length", "duration_s"}
        # Atomic: the conversion appears at ``out`` (replacing what is there) only once it is complete.
        writer = EpisodeStore.create(out, new_meta, overwrite=overwrite, robot_from=src_path, atomic=True)
        done_frames = 0
        stage = f"convert -> {dst.name}"
        report(Tick(stage, 0, store.num_frames, {"episodes": 0}))
        try:
            for block in _blocks(store.episode_lengths):
                episodes = [store.read_episode(int(i)) for i in block]
                where = f"{src_path} episodes {block[0]}..{block[-1]}"
                lengths = [len(ep["action"]) for ep in episodes]
                seg = Segments(np.cumsum(lengths))
                anchor, source = episode_anchors(episodes, ctx, src, where)
                anchor_sources[source] = anchor_sources.get(source, 0) + len(block)
                action = np.concatenate([ep["action"] for ep in episodes])
                q_measured = None
                if conv.needs_ik:
                    frames = {k: np.concatenate([ep[k] for ep in episodes]) for k in ("sim.state", "obs.joint_pos")
                              if k in episodes[0]}
                    q_measured, _ = measured_joints(frames, ctx, where)
                new_action, ik_results = conv.convert(action, anchor, seg, where, q_measured)
                if check is None and conv.crosses and ctx is not None and src.rep.space == "joint":
                    q = conv.commands(action, anchor, seg, where).q  # type: ignore[union-attr]
                    check = fk_check(ctx, q, np.random.default_rng(0))
                batch = []
                for k, (i, ep) in enumerate(zip(block, episodes)):
                    s, t = seg.starts[k], seg.ends[k]
                    data = {key: v for key, v in ep.items() if key in new_meta.features}
                    data["action"] = new_action[s:t]
                    if dst.anchor_key == EE_ANCHOR_KEY:
                        data[EE_ANCHOR_KEY] = np.repeat(anchor.pose7()[k][None], t - s, axis=0)
                    elif dst.anchor_key == JOINT_ANCHOR_KEY:
                        data[JOINT_ANCHOR_KEY] = np.repeat(anchor.q[k][None], t - s, axis=0)
                    info = {key: v for key, v in store.episode_info(int(i)).items() if key not in skip}
                    info["source_episode"] = int(i)
                    if ik_results is not None and ik is not None:
                        r = ik_results[k]
                        ik.add(int(i), r)
                        data[IK_KEY] = r.converged
                        info.update(ik_failed_frames=int((~r.converged).sum()), ik_max_pos_err=float(r.pos_err.max()),
                                    ik_max_rot_err=float(r.rot_err.max()))
                    batch.append((data, info))
                writer.append_episodes(batch, origin=[f"{src_path} episode {int(i)}" for i in block])
                done_frames += int(seg.ends[-1])
                report(Tick(stage, done_frames, store.num_frames, {"episodes": int(block[-1]) + 1}))
            record = {
                "op": "convert",
                "from": str(src_path),
                "from_action": meta.action.to_json(),
                "to": dst.name,
                "to_action": dst_spec.to_json(),
                "robot": ctx.record if ctx else meta.robot,
                "anchor_source": anchor_sources,
                "ik": ({"config": asdict(opts.ik), **ik.to_json()} if ik else None),
                "fk_check": check,
                "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            }
            writer.update_meta(provenance=[*new_meta.provenance, record])
        except BaseException:
            writer.abandon()  # no half-converted store is left behind; ``out`` keeps what it held
            raise
        writer.close()
    return ConvertResult(str(out), src.name, dst.name, store.num_episodes, done_frames,
                         time.perf_counter() - started, anchor_sources, ik, check)


def _context_for(meta: StoreMeta, where: StorePath, opts: ConvertOptions) -> RobotContext | None:
    """Load the robot when the conversion (or its anchors) needs one; None when it does not."""
    src_rep = reps.get_representation(meta.action.name, where / "zarr.json")
    dst_rep = reps.get_representation(opts.to)
    needs = src_rep.space != dst_rep.space or opts.robot is not None
    if not needs and not (meta.robot or {}).get("config"):
        return None
    purpose = f"converting {src_rep.name} to {dst_rep.name}"
    try:
        return load_context(meta, where, opts.robot, purpose)
    except DemoError:
        if needs:
            raise
        return None


def _target_meta(meta: StoreMeta, src: ActionFormat, dst: ActionFormat, spec: Any, with_ik: bool) -> StoreMeta:
    new = StoreMeta.from_json(meta.to_json())
    features = {k: v for k, v in new.features.items()
                if k != "action" and k not in (EE_ANCHOR_KEY, JOINT_ANCHOR_KEY)}
    anchor_spec = dst.anchor_feature()
    if anchor_spec is not None and dst.anchor_key:
        features[dst.anchor_key] = anchor_spec
    if with_ik:
        features[IK_KEY] = FeatureSpec((), "bool", "IK reached the commanded EE pose within tolerance", "")
    new.action = spec
    new.features = {"action": spec.feature(), **features}
    return new


def _blocks(lengths: np.ndarray) -> list[np.ndarray]:
    """Consecutive episode index groups of about BLOCK_FRAMES frames."""
    blocks, current, total = [], [], 0
    for i, n in enumerate(lengths):
        current.append(i)
        total += int(n)
        if total >= BLOCK_FRAMES:
            blocks.append(np.array(current))
            current, total = [], 0
    if current:
        blocks.append(np.array(current))
    return blocks
