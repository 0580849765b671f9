"""`demo collect --source vr`: tracked hand poses retargeted onto the robot.

Input, ``POSES.jsonl`` (one JSON object a line, blank lines allowed)::

    {"episode_seed": 1234}                                   # header: starts an episode
    {"t": 0.000, "pos": [x, y, z], "quat": [w, x, y, z], "grip": 0.0}
    {"t": 0.016, "pos": [...], "quat": [...], "grip": 0.0, "engaged": true}
    ...
    {"episode_seed": 99, "operator": "alice", "task": "pick"}   # the next episode

- ``t``: seconds, strictly increasing within an episode (any rate; VR streams at 30-90 Hz).
- ``pos``: hand position in the tracker's frame (tracker units, scaled to metres by the
  calibration). ``quat``: hand orientation, unit quaternion w-x-y-z (norm within 1 +- 0.01).
- ``grip``: 0 = open .. 1 = closed (the gripper command). ``engaged`` (optional, default true):
  false while the clutch is held, i.e. the hand moves without moving the robot.
- Header keys: ``episode_seed`` (the ``env.reset`` seed of the episode's initial state), and
  optional ``operator`` (who demonstrated) and ``task`` (checked against ``--task``). Poses before
  any header form one episode that starts from ``episode_seed(seed, 0)``.

Pipeline per episode (all frames named):

1. **Smoothing** of tracker jitter: a One Euro filter (Casiez et al. 2012) in the tracker frame at
   the tracker's own rate, restarted whenever the clutch engages: a low cutoff at rest (jitter
   removed), rising with hand speed (little lag in fast moves).
2. **Resampling** to the control rate ``env.fps``: linear (positions, grip) and normalised linear
   (quaternions) interpolation between engaged samples.
3. **Calibration** tracker -> robot base (:class:`Calibration`), and **clutch + motion scaling**
   (:class:`HandMapper`): while engaged, the EE target is the anchor pose plus ``scale`` times the
   hand's displacement since the clutch engaged (rotations are not scaled). The anchor is the
   pose the commanded arm configuration reaches when the clutch engages, except that the first
   engage with a ``--calib`` file puts the EE where the calibration maps the hand (absolute).
   Without a calibration file the tracker's rotation is aligned on the first pose: the hand's
   first orientation is taken to be the EE's orientation at reset.
4. **Retargeting** (:class:`demo.collect.retarget.Retargeter`, mink or placo): joint targets,
   with frames whose hand pose is not reached flagged in ``info.ik_ok``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.collect.human import (
    HumanCollectResult,
    HumanCommand,
    HumanConfig,
    InputEpisode,
    as_float,
    as_floats,
    check_task,
    check_time,
    episode_info,
    record_episodes,
    play_recording,
    reset_seed,
)
from demo.collect.retarget import IK_BACKENDS, Retargeter, RetargetParams, RetargetStep
from demo.errors import DemoError
from demo.progress import Progress
from demo.sim.geometry import mat_to_quat, quat_conj, quat_mul

QUAT_NORM_TOL = 0.01
MAX_POSITION = 1000.0  # tracker units (metres or so): a hand this far from the origin is a broken sample
POSE_KEYS = {"t", "pos", "quat", "grip", "engaged"}
HEADER_KEYS = {"episode_seed", "operator", "task"}


# ------------------------------------------------------------------------------ input
@dataclass
class PoseTrack:
    """One episode of tracked hand poses, tracker frame."""

    episode: InputEpisode  # where it starts in the file, its header
    t: np.ndarray  # (N,) s
    pos: np.ndarray  # (N, 3) tracker units
    quat: np.ndarray  # (N, 4) unit, wxyz
    grip: np.ndarray  # (N,) 0 open .. 1 closed
    engaged: np.ndarray  # (N,) bool

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number")


def parse_poses(path: str | Path, task: str | None = None) -> list[PoseTrack]:
    """Read and validate a pose file; any problem is a DemoError naming ``path:line``."""
    path = Path(path)
    if not path.is_file():
        raise DemoError(path, "pose file not found")
    tracks: list[PoseTrack] = []
    header: tuple[int, int | None, str | None] | None = None  # (line, seed, operator)
    rows: list[tuple[float, np.ndarray, np.ndarray, float, bool]] = []
    first_pose_line = 0

    def close_episode() -> None:
        if header is None and not rows:
            return
        line, seed, operator = header if header is not None else (first_pose_line, None, None)
        if not rows:
            raise DemoError(f"{path}:{line}", "episode has no poses")
        t, pos, quat, grip, engaged = zip(*rows)
        tracks.append(PoseTrack(InputEpisode(line, seed, operator), t=np.array(t), pos=np.array(pos),
                                quat=np.array(quat), grip=np.array(grip), engaged=np.array(engaged, dtype=bool)))

    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        raise DemoError(path, f"not a UTF-8 text file ({exc.reason})") from None
    for number, text in enumerate(lines, start=1):
        if not text.strip():
            continue
        where = f"{path}:{number}"
        try:
            obj = json.loads(text, parse_constant=_reject_constant)
        except ValueError as exc:
            raise DemoError(where, f"not valid JSON ({exc})") from None
        if not isinstance(obj, dict):
            raise DemoError(where, f"expected a JSON object, got {type(obj).__name__}")
        if "t" not in obj:
            unknown = sorted(set(obj) - HEADER_KEYS)
            if unknown or "episode_seed" not in obj:
                raise DemoError(where, f"neither a pose (needs 't') nor a header (needs 'episode_seed'); "
                                       f"unknown keys: {', '.join(unknown) or 'none'}")
            seed = obj["episode_seed"]
            if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
                raise DemoError(where, f"'episode_seed' must be a non-negative integer, got {seed!r}")
            operator = obj.get("operator")
            if operator is not None and (not isinstance(operator, str) or not operator):
                raise DemoError(where, "'operator' must be a non-empty string")
            if task is not None:
                check_task(path, number, obj.get("task"), task)
            close_episode()
            header, rows = (number, seed, operator), []
            continue
        unknown = sorted(set(obj) - POSE_KEYS)
        if unknown:
            raise DemoError(where, f"unknown key(s) {', '.join(unknown)} (a pose has {', '.join(sorted(POSE_KEYS))})")
        missing = sorted({"t", "pos", "quat", "grip"} - set(obj))
        if missing:
            raise DemoError(where, f"pose lacks {', '.join(missing)}")
        t = as_float(where, "t", obj["t"])
        check_time(where, t, rows[-1][0] if rows else None, rows[0][0] if rows else None)
        pos = as_floats(where, "pos", obj["pos"], 3)
        if float(np.max(np.abs(pos))) > MAX_POSITION:
            raise DemoError(where, f"'pos' is more than {MAX_POSITION:g} tracker units from the origin")
        quat = as_floats(where, "quat", obj["quat"], 4)
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > QUAT_NORM_TOL:
            raise DemoError(where, f"quaternion is not unit length (norm {norm:.4g}; expected w, x, y, z with norm 1)")
        grip = as_float(where, "grip", obj["grip"])
        if not 0.0 <= grip <= 1.0:
            raise DemoError(where, f"'grip' must be within 0 (open) .. 1 (closed), got {grip:g}")
        engaged = obj.get("engaged", True)
        if not isinstance(engaged, bool):
            raise DemoError(where, f"'engaged' must be true or false, got {engaged!r}")
        if not rows and header is None:
            first_pose_line = number
        rows.append((t, pos, quat / norm, grip, engaged))
    close_episode()
    if not tracks:
        raise DemoError(path, "no poses in the file")
    return tracks


# ------------------------------------------------------------------------------ calibration
@dataclass(frozen=True)
class Calibration:
    """Tracker frame -> robot base frame: ``p_base = translation + scale * R p_tracker``.

    ``hand_to_ee``: the EE orientation when the hand is at orientation ``q``: ``R q hand_to_ee``.
    """

    rotation: np.ndarray  # wxyz, tracker -> base
    translation: np.ndarray  # m, base frame
    scale: float = 1.0  # m per tracker unit
    hand_to_ee: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))

    def to_json(self) -> dict[str, Any]:
        return {"rotation": self.rotation.tolist(), "translation": self.translation.tolist(), "scale": self.scale,
                "hand_to_ee": self.hand_to_ee.tolist()}


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration JSON: ``rotation`` (wxyz or 3x3), ``translation`` (m), optional ``scale``
    (m per tracker unit, default 1) and ``hand_to_ee`` (wxyz, default identity)."""
    path = Path(path)
    if not path.is_file():
        raise DemoError(path, "calibration file not found")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"), parse_constant=_reject_constant)
    except (ValueError, UnicodeDecodeError) as exc:
        raise DemoError(path, f"not valid JSON ({exc})") from None
    where = str(path)
    if not isinstance(raw, dict):
        raise DemoError(where, "expected a JSON object with rotation, translation")
    unknown = sorted(set(raw) - {"rotation", "translation", "scale", "hand_to_ee"})
    if unknown:
        raise DemoError(where, f"unknown key(s) {', '.join(unknown)}")
    for key in ("rotation", "translation"):
        if key not in raw:
            raise DemoError(where, f"calibration lacks '{key}'")
    rot = raw["rotation"]
    if isinstance(rot, list) and len(rot) == 3 and all(isinstance(r, list) for r in rot):
        mat = np.stack([as_floats(where, "rotation", r, 3) for r in rot])
        if not np.allclose(mat @ mat.T, np.eye(3), atol=1e-3) or np.linalg.det(mat) < 0:
            raise DemoError(where, "'rotation' matrix is not a rotation (orthonormal, det +1)")
        quat = mat_to_quat(mat)
    else:
        quat = _unit_quat(where, "rotation", rot)
    scale = as_float(where, "scale", raw.get("scale", 1.0))
    if scale <= 0:
        raise DemoError(where, f"'scale' must be > 0, got {scale:g}")
    hand = _unit_quat(where, "hand_to_ee", raw.get("hand_to_ee", [1.0, 0.0, 0.0, 0.0]))
    return Calibration(quat, as_floats(where, "translation", raw["translation"], 3), scale, hand)


def _unit_quat(where: str, name: str, value: Any) -> np.ndarray:
    q = as_floats(where, name, value, 4)
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > QUAT_NORM_TOL:
        raise DemoError(where, f"'{name}' is not a unit quaternion (norm {n:.4g})")
    return q / n


# ------------------------------------------------------------------------------ smoothing
@dataclass(frozen=True)
class SmoothingParams:
    """One Euro filter settings; ``min_cutoff <= 0`` turns smoothing off."""

    min_cutoff: float = 2.0  # Hz, position cutoff at rest
    beta: float = 10.0  # Hz per (tracker unit / s): cutoff increase with speed
    rot_min_cutoff: float = 2.0  # Hz, orientation cutoff at rest
    rot_beta: float = 2.0  # Hz per (rad / s)
    d_cutoff: float = 1.0  # Hz, cutoff of the speed estimate


class OneEuro:
    """One Euro filter of a vector signal sampled at irregular times (Casiez et al., CHI 2012)."""

    def __init__(self, min_cutoff: float, beta: float, d_cutoff: float):
        self.min_cutoff, self.beta, self.d_cutoff = min_cutoff, beta, d_cutoff
        self.x: np.ndarray | None = None
        self.dx: np.ndarray | None = None

    @staticmethod
    def _alpha(cutoff: float, dt: float) -> float:
        tau = 1.0 / (2.0 * math.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def reset(self) -> None:
        self.x = self.dx = None

    def __call__(self, x: np.ndarray, dt: float, speed_scale: float = 1.0) -> np.ndarray:
        if self.x is None or dt <= 0:
            self.x, self.dx = x.copy(), np.zeros_like(x)
            return self.x.copy()
        a_d = self._alpha(self.d_cutoff, dt)
        self.dx = a_d * (x - self.x) / dt + (1.0 - a_d) * self.dx
        cutoff = self.min_cutoff + self.beta * speed_scale * math.sqrt(float(self.dx @ self.dx))
        a = self._alpha(cutoff, dt)
        self.x = a * x + (1.0 - a) * self.x
        return self.x.copy()


def smooth(track: PoseTrack, params: SmoothingParams = SmoothingParams()) -> PoseTrack:
    """The track with positions and orientations One-Euro filtered, restarting at each engage."""
    if params.min_cutoff <= 0:
        return track
    pos_f = OneEuro(params.min_cutoff, params.beta, params.d_cutoff)
    rot_f = OneEuro(params.rot_min_cutoff, params.rot_beta, params.d_cutoff)
    pos = np.empty_like(track.pos)
    quat = np.empty_like(track.quat)
    prev_t, prev_q, was_engaged = None, None, False
    for i in range(len(track.t)):
        if track.engaged[i] and not was_engaged:
            pos_f.reset()
            rot_f.reset()
            prev_t = None
        q = track.quat[i]
        if prev_q is not None and float(q @ prev_q) < 0:
            q = -q  # same rotation, continuous sign
        dt = 0.0 if prev_t is None else float(track.t[i] - prev_t)
        pos[i] = pos_f(track.pos[i], dt)
        # |d quat / dt| is half the angular speed: scale so rot_beta is per rad/s.
        fq = rot_f(q, dt, speed_scale=2.0)
        quat[i] = fq / math.sqrt(float(fq @ fq))
        prev_t, prev_q, was_engaged = float(track.t[i]), quat[i], bool(track.engaged[i])
    return dataclasses.replace(track, pos=pos, quat=quat)


# ------------------------------------------------------------------------------ resampling
@dataclass
class ControlStream:
    """A pose track sampled at the control rate: step k is at ``t0 + k / fps``."""

    pos: np.ndarray  # (K, 3) tracker frame
    quat: np.ndarray  # (K, 4)
    grip: np.ndarray  # (K,)
    engaged: np.ndarray  # (K,) bool

    def __len__(self) -> int:
        return len(self.grip)


def resample(track: PoseTrack, fps: float) -> ControlStream:
    """Interpolate between engaged neighbours; hold the last sample elsewhere."""
    t = track.t - track.t[0]
    k = int(math.floor(t[-1] * fps + 1e-9)) + 1
    tk = np.arange(k) / fps
    i = np.clip(np.searchsorted(t, tk, side="right") - 1, 0, len(t) - 1)
    j = np.minimum(i + 1, len(t) - 1)
    span = np.where(j > i, t[j] - t[i], 1.0)
    w = np.where((j > i) & track.engaged[i] & track.engaged[j], np.clip((tk - t[i]) / span, 0.0, 1.0), 0.0)
    pos = track.pos[i] + w[:, None] * (track.pos[j] - track.pos[i])
    qi, qj = track.quat[i], track.quat[j].copy()
    qj[np.sum(qi * qj, axis=1) < 0] *= -1.0
    quat = qi + w[:, None] * (qj - qi)
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    grip = track.grip[i] + w * (track.grip[j] - track.grip[i])
    return ControlStream(pos, quat, grip, track.engaged[i].copy())


# ------------------------------------------------------------------------------ clutch + scaling
class HandMapper:
    """Hand pose (tracker frame) -> EE target (base frame): calibration, clutch, motion scaling."""

    def __init__(self, calibration: Calibration | None = None, scale: float = 1.0):
        if not scale > 0:
            raise DemoError("--scale", f"must be > 0, got {scale}")
        self.calibration = calibration
        self.scale = float(scale)
        self.reset()

    def reset(self) -> None:
        self._rot: np.ndarray | None = None if self.calibration is None else self.calibration.rotation
        self._anchor: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None  # hand p, q; ee p, q
        self._engaged_before = False

    def __call__(
        self, pos: np.ndarray, quat: np.ndarray, engaged: bool, robot_pose: Callable[[], tuple[np.ndarray, np.ndarray]]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """EE target (m, wxyz; base frame), or None while the clutch is released (hold)."""
        if not engaged:
            self._anchor = None
            return None
        cal = self.calibration
        if self._anchor is None:
            if cal is not None and not self._engaged_before:
                ee_p = cal.translation + cal.scale * _rotate(cal.rotation, pos)
                ee_q = quat_mul(quat_mul(cal.rotation, quat), cal.hand_to_ee)
            else:
                ee_p, ee_q = robot_pose()
                if self._rot is None:  # align the tracker on the first pose
                    self._rot = quat_mul(ee_q, quat_conj(quat))
            self._anchor = (pos.copy(), quat.copy(), np.array(ee_p), np.array(ee_q))
            self._engaged_before = True
        hand_p, hand_q, ee_p, ee_q = self._anchor
        rot = self._rot
        assert rot is not None
        gain = self.scale * (cal.scale if cal is not None else 1.0)
        target_p = ee_p + gain * _rotate(rot, pos - hand_p)
        delta = quat_mul(quat_mul(rot, quat_mul(quat, quat_conj(hand_q))), quat_conj(rot))
        target_q = quat_mul(delta, ee_q)
        return target_p, target_q / math.sqrt(float(target_q @ target_q))


def _rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.empty(3)
    mujoco.mju_rotVecQuat(out, np.asarray(v, dtype=np.float64), np.asarray(quat, dtype=np.float64))
    return out


# ------------------------------------------------------------------------------ collection
@dataclass(frozen=True)
class VRSettings:
    calib: str | None = None
    scale: float = 1.0
    ik: str = "mink"
    smoothing: SmoothingParams = field(default_factory=SmoothingParams)
    retarget: RetargetParams = field(default_factory=RetargetParams)


class HandRetargeter:
    """Per control step: hand pose (tracker frame) -> EE target -> joint targets, and the flag."""

    def __init__(self, mapper: HandMapper, retargeter: Retargeter):
        self.mapper = mapper
        self.retargeter = retargeter

    def reset(self, q_arm: np.ndarray | None = None) -> None:
        self.mapper.reset()
        self.retargeter.reset(q_arm)

    def __call__(self, pos: np.ndarray, quat: np.ndarray, engaged: bool) -> tuple[RetargetStep, np.ndarray]:
        """(joint targets + flag, EE target (7,): m + wxyz, base frame). Clutch released: hold."""
        rt = self.retargeter
        pose = self.mapper(pos, quat, engaged, rt.ee_pose)
        if pose is None:
            step = rt.hold()
            pose = rt.ee_pose()
        else:
            step = rt(*pose)
        return step, np.concatenate(pose)


def vr_episode(env: Any, track: PoseTrack, seed: int, hand: HandRetargeter, settings: VRSettings
               ) -> tuple[Any, np.ndarray, np.ndarray]:
    """Retarget one pose track from ``env.reset(seed)``: (Episode, ik_ok [T,1], ik_error [T,2])."""
    stream = resample(smooth(track, settings.smoothing), env.fps)
    env.reset(seed)
    hand.reset()
    last = len(stream) - 1

    def command_at(t: int) -> HumanCommand:
        k = min(t, last)
        step, target = hand(stream.pos[k], stream.quat[k], bool(stream.engaged[k]))
        return HumanCommand(step.q, float(stream.grip[k]), target, step.ok, (step.pos_err, step.rot_err))

    return play_recording(env, seed, len(stream), command_at)


def collect_vr(
    task: str,
    input_jsonl: str | Path,
    out: str | Path,
    seed: int = 0,
    *,
    calib: str | Path | None = None,
    scale: float = 1.0,
    ik: str = "mink",
    smoothing: SmoothingParams | float = SmoothingParams(),
    operator: str | None = None,
    robot: str | None = None,
    task_options: dict[str, Any] | None = None,
    cameras: tuple[tuple[str, int, int], ...] = (),
    instruction: str = "",
    append: bool = False,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> HumanCollectResult:
    """Retarget every episode of a pose file into the store at ``out`` (see the module docstring).

    ``calib``: calibration JSON (tracker -> base); None aligns the first pose to the EE at reset.
    ``scale``: robot motion per hand motion. ``ik``: "mink" or "placo". ``smoothing``: One Euro
    settings, or just the position cutoff at rest in Hz (0 = no smoothing). ``operator``: None
    takes each episode's header ``operator``, else "human". ``progress``: a tick per committed episode.
    """
    if not isinstance(smoothing, SmoothingParams):
        if not float(smoothing) >= 0:
            raise DemoError("--smoothing", f"must be >= 0 Hz, got {smoothing}")
        smoothing = SmoothingParams(min_cutoff=float(smoothing))
    if ik not in IK_BACKENDS:
        raise DemoError("--ik", f"unknown IK backend {ik!r} (choose from {', '.join(IK_BACKENDS)})")
    if not scale > 0:
        raise DemoError("--scale", f"must be > 0, got {scale}")
    calibration = load_calibration(calib) if calib is not None else None
    tracks = parse_poses(input_jsonl, task)
    settings = VRSettings(str(calib) if calib else None, float(scale), ik, smoothing)
    config = HumanConfig(
        task=task, source="vr", input=str(input_jsonl), seed=seed, operator=operator, robot=robot,
        task_options=dict(task_options or {}), cameras=tuple(cameras),
        settings={"calib": settings.calib, "calibration": calibration.to_json() if calibration else None,
                  "scale": settings.scale, "ik": ik, "smoothing": asdict(smoothing)},
        instruction=instruction,
    )
    state: dict[str, Any] = {}

    def run(env: Any, index: int, count: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if "hand" not in state:
            state["hand"] = HandRetargeter(HandMapper(calibration, scale), Retargeter(env, ik, settings.retarget))
        track = tracks[index]
        s = reset_seed(track.episode, seed, index)
        episode, ik_ok, ik_err = vr_episode(env, track, s, state["hand"], settings)
        data = dict(episode.data)
        data["info.ik_ok"], data["info.ik_error"] = ik_ok, ik_err
        info = episode_info(config, track.episode, s, episode.success, episode.first_success_step, ik_ok)
        info["ik"] = ik
        return data, info

    return record_episodes(config, len(tracks), run, out, append=append, overwrite=overwrite, progress=progress)
