"""ee7 for each arm of a robot of several arms (:mod:`demo.sim.arms`), and back: ``demo convert STORE --to ee7
--robot ARMS.toml --check``.

A store recorded in a Gymnasium environment whose action is those arms' joint targets (gym-aloha's 14-D,
:mod:`demo.sim.aloha_scene`) is re-expressed arm by arm: each arm's joint targets become its ee7, the canonical
``[dx, dy, dz, droll, dpitch, dyaw, gripper]`` of :mod:`demo.convert.representations` (the commanded TCP, the arm
config's ``ee_site``, in the arm's own base frame; deltas between commands, anchored at the measured joints of
frame 0), and the arms' ee7 are concatenated in the robot's order (``left.dx`` ... ``left.gripper``,
``right.dx`` ...; 7 per arm). The gripper becomes ee7's closedness (0 open, 1 closed) from the environment's
gripper command at open and closed (``gripper_command``). Back: each arm's ee7 is decoded into commanded poses
and solved by IK on that arm (mink, warm-started from the measured joints), its closedness into the gripper
command.

``--out`` writes the converted store: the arms' ee7 as its action (``params.arms`` names the arms), each arm's
anchor pose side by side in ``info.ee_anchor`` (7 per arm: position + quaternion wxyz, that arm's base frame),
every other feature and episode column kept, atomically (nothing at ``--out`` until it is complete).

The check, as for one arm: every selected episode is replayed in the environment from its seed twice, with the
recorded joint targets and with the targets after ee7 and back; the error is the largest distance between the
two replays' TCPs (each arm's ``ee_site`` by FK of the measured joints, m and rad) and whether they succeed
alike. Measured joints come from ``obs.agent_pos`` laid out as the action (gym-aloha's).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from demo.convert import representations as reps
from demo.convert.check import CheckReport, EpisodeCheck
from demo.convert.context import RobotContext
from demo.convert.convert import Converter
from demo.convert.ik import IKConfig
from demo.convert.kinematics import Kinematics
from demo.convert.representations import EE_ANCHOR_KEY, Anchor, Segments
from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.sim import make_env
from demo.sim.arms import MEASURED_KEY, ArmsConfig, closedness_from_gripper, gripper_from_closedness, load_arms
from demo.sim.foreign import is_foreign
from demo.sim.geometry import angle_between
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.store.location import same_store, store_path



class ArmsEE7:
    """Joint targets of several arms <-> each arm's ee7, concatenated (module docstring)."""

    def __init__(self, arms: ArmsConfig, fps: float, gripper_command: tuple[float, float], ik: IKConfig | None = None):
        self.arms, self.fps, self.gripper_command = arms, float(fps), gripper_command
        ee7 = reps.make_format("ee7")
        self.contexts, self.to_ee7, self.from_ee7 = [], [], []
        for arm in arms.arms:
            kin = Kinematics(arm.spec().compile(), arm.arm_joints, arm.ee_site, arm.base_body, where=arm.config_path)
            ctx = RobotContext(arm, kin, None, None, None)
            joints = reps.make_format("joint_pos", joint_names=arm.arm_joints)
            self.contexts.append(ctx)
            self.to_ee7.append(Converter(joints, ee7, fps, ctx))
            self.from_ee7.append(Converter(ee7, joints, fps, ctx, ik))

    def spec(self) -> ActionSpec:
        """The converted store's action: each arm's ee7 dimensions, prefixed by its name."""
        one = reps.make_format("ee7").spec()
        names = tuple(f"{arm}.{n}" for arm in self.arms.arm_names for n in one.names)
        params = {**one.params, "arms": list(self.arms.arm_names), "from_gripper_command": list(self.gripper_command)}
        return ActionSpec(one.name, names, one.units * len(self.arms.arms), frame=one.frame,
                          description=f"each arm's ee7, concatenated ({', '.join(self.arms.arm_names)})", params=params)

    def anchor_feature(self) -> FeatureSpec:
        one = reps.make_format("ee7").anchor_feature()
        assert one is not None
        names = tuple(f"{arm}.{n}" for arm in self.arms.arm_names for n in one.names)
        return FeatureSpec((7 * len(self.arms.arms),), one.dtype, f"each arm's {one.description}", one.units, names)

    def anchors(self, measured_first: np.ndarray) -> list[Anchor]:
        """Each arm's anchor from the measured joints of every episode's frame 0 ([E, A], laid out as the action)."""
        out = []
        for ctx, part in zip(self.contexts, self.arms.arm_slices()):
            q = measured_first[:, part][:, :-1].astype(np.float64)
            pos, rot = ctx.kin.fk(q)
            out.append(Anchor(q=q, pos=pos, rot=rot))
        return out

    def encode(self, action: np.ndarray, anchors: list[Anchor], seg: Segments) -> np.ndarray:
        """Joint-target actions [N, A] -> the arms' ee7 [N, 7 x arms]."""
        parts = []
        for conv, part, anchor in zip(self.to_ee7, self.arms.arm_slices(), anchors):
            arm = action[:, part].astype(np.float64)
            joint_pos = np.concatenate([arm[:, :-1], closedness_from_gripper(arm[:, -1:], self.gripper_command)], axis=1)
            parts.append(conv.convert(joint_pos, anchor, seg)[0])
        return np.concatenate(parts, axis=1)

    def decode(self, ee7: np.ndarray, anchors: list[Anchor], seg: Segments, measured: np.ndarray | None = None
               ) -> tuple[np.ndarray, int]:
        """The arms' ee7 [N, 7 x arms] -> joint-target actions [N, A] by IK on each arm, and the frames whose IK did
        not converge. ``measured`` [N, A]: the warm starts (else each frame starts from the last solution)."""
        parts, failed = [], 0
        for i, (conv, part, anchor) in enumerate(zip(self.from_ee7, self.arms.arm_slices(), anchors)):
            warm = measured[:, part][:, :-1].astype(np.float64) if measured is not None else None
            joint_pos, results = conv.convert(ee7[:, 7 * i:7 * (i + 1)], anchor, seg, q_measured=warm)
            failed += sum(int((~r.converged).sum()) for r in results or [])
            parts.append(np.concatenate([joint_pos[:, :-1], gripper_from_closedness(joint_pos[:, -1:], self.gripper_command)], axis=1))
        return np.concatenate(parts, axis=1), failed

    def tcp(self, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each arm's TCP from measured joints [T, A]: positions [T, arms, 3] (m), rotations [T, arms, 3, 3]."""
        poses = [ctx.kin.fk(measured[:, part][:, :-1].astype(np.float64))
                 for ctx, part in zip(self.contexts, self.arms.arm_slices())]
        return np.stack([p for p, _ in poses], axis=1), np.stack([r for _, r in poses], axis=1)


def _replay(env: Any, seed: int, actions: np.ndarray) -> tuple[np.ndarray, bool]:
    """The measured joints after each step ([T, A]) of ``actions`` from ``env.reset(seed)``, and the success."""
    env.reset(seed)
    measured = np.empty((len(actions), actions.shape[1]))
    success = False
    for t, a in enumerate(actions):
        _, _, succeeded, _, _ = env.step(a.astype(np.float32))
        measured[t] = env.frame()[MEASURED_KEY]
        success = success or bool(succeeded)
    return measured, success


def arms_replay_check(path: str | Path, robot: str, *, episodes: Any = None, ik: IKConfig | None = None,
                      progress: Progress | None = None) -> CheckReport:
    """Replay the selected episodes of the store at ``path`` with their recorded joint targets and with the targets
    after each arm's ee7 and back (module docstring); one :class:`EpisodeCheck` per episode."""
    path = store_path(path)
    tell = or_silent(progress)
    with EpisodeStore.open(path) as store:
        meta = store.meta
        arms, task, env = _open_source(store, robot)
        report = CheckReport(str(path), "joint targets", "ee7 per arm", replayed_from="each episode's seed")
        chosen = store.select(episodes)
        try:
            where = f"--env {task}"
            conversion = ArmsEE7(arms, meta.fps, arms.check_env(env, where), ik)
            tell(Tick("replay check", 0, len(chosen)))
            for i in chosen:
                ep = store.read_episode(int(i))
                seg = Segments.single(len(ep["action"]))
                measured = ep[MEASURED_KEY].astype(np.float64)
                anchors = conversion.anchors(measured[:1])
                ee7 = conversion.encode(ep["action"], anchors, seg).astype(np.float32)  # as a store would hold it
                back, failed = conversion.decode(ee7.astype(np.float64), anchors, seg, measured)
                seed = int(store.episode_info(int(i))["seed"])
                m1, ok1 = _replay(env, seed, ep["action"])
                m2, ok2 = _replay(env, seed, back)
                (p1, r1), (p2, r2) = conversion.tcp(m1), conversion.tcp(m2)
                report.episodes.append(EpisodeCheck(
                    episode=int(i), frames=len(back),
                    max_pos_err_m=float(np.linalg.norm(p1 - p2, axis=-1).max()),
                    max_rot_err_rad=float(angle_between(r1.reshape(-1, 3, 3), r2.reshape(-1, 3, 3)).max()),
                    recorded_success=bool(store.episode_info(int(i))["success"]),
                    original_success=ok1, converted_success=ok2, ik_failed_steps=failed,
                ))
                agree = sum(e.agree for e in report.episodes)
                tell(Tick("replay check", len(report.episodes), len(chosen), {"agree": f"{agree}/{len(report.episodes)}"}))
        finally:
            env.close()
    return report


def _open_source(store: EpisodeStore, robot: str) -> tuple[ArmsConfig, str, Any]:
    """The robot, the environment's task name and the environment (to be closed) of a store to convert."""
    meta = store.meta
    task = (meta.task or {}).get("name")
    if not is_foreign(task):
        raise DemoError(store.path, f"was recorded in {task!r}; ee7 for each arm converts a Gymnasium environment's "
                                    "joint targets (e.g. --env demo.sim.aloha_scene:transfer_cube)")
    if MEASURED_KEY not in meta.features:
        raise DemoError(store.path, f"has no {MEASURED_KEY} (the arms' measured joints, laid out as the action)")
    arms = load_arms(robot)
    return arms, str(task), make_env(task, **dict((meta.task or {}).get("options") or {}))


def convert_arms_store(src: str | Path, out: str | Path, robot: str, *, overwrite: bool = False,
                       progress: Progress | None = None) -> dict[str, Any]:
    """Write a copy of the store at ``src`` with each arm's ee7 as its action to ``out`` (module docstring)."""
    started = time.perf_counter()
    tell = or_silent(progress)
    src, out = store_path(src), store_path(out)
    with EpisodeStore.open(src) as store:
        if same_store(out, store.path):
            raise DemoError(out, "is the source store; write the conversion elsewhere")
        arms, task, env = _open_source(store, robot)
        try:
            conversion = ArmsEE7(arms, store.meta.fps, arms.check_env(env, f"--env {task}"))
        finally:
            env.close()
        meta = StoreMeta.from_json(store.meta.to_json())
        spec = conversion.spec()
        meta.action = spec
        meta.features = {"action": spec.feature(), EE_ANCHOR_KEY: conversion.anchor_feature(),
                         **{k: v for k, v in meta.features.items() if k not in ("action", EE_ANCHOR_KEY)}}
        meta.provenance = [*meta.provenance, {"op": "convert", "from": str(src), "from_action": store.meta.action.to_json(),
                                              "to": "ee7 per arm", "robot": str(robot),
                                              "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}]
        writer = EpisodeStore.create(out, meta, overwrite=overwrite, robot_from=src, atomic=True)
        skip = {"episode_index", "start", "length", "duration_s"}
        tell(Tick("convert -> ee7 per arm", 0, store.num_episodes))
        try:
            for i in range(store.num_episodes):
                ep = store.read_episode(i)
                anchors = conversion.anchors(ep[MEASURED_KEY][:1])
                data = {k: v for k, v in ep.items() if k in meta.features}
                data["action"] = conversion.encode(ep["action"], anchors, Segments.single(len(ep["action"])))
                data[EE_ANCHOR_KEY] = np.repeat(np.concatenate([a.pose7() for a in anchors], axis=1), len(ep["action"]), 0)
                info = {k: v for k, v in store.episode_info(i).items() if k not in skip}
                writer.append_episodes([(data, {**info, "source_episode": i})], origin=[f"{src} episode {i}"])
                tell(Tick("convert -> ee7 per arm", i + 1, store.num_episodes))
        except BaseException:
            writer.abandon()  # no half-converted store is left behind
            raise
        writer.close()
        return {"out": str(out), "from": "joint targets", "to": "ee7 per arm", "arms": list(arms.arm_names),
                "episodes": store.num_episodes, "frames": store.num_frames, "seconds": time.perf_counter() - started}
