"""Action representations: the registry, and the exact meaning of every number in them.

CONVENTIONS (the one place they are written down; tests pin each of them)
=========================================================================

Frames and units
  * Every end-effector (EE) pose is the pose of the robot config's ``ee_site`` expressed in the
    frame of its ``base_body`` (the *base frame*), never the world frame. Positions in m, angles
    in rad, time step = 1 / fps of the store (one action per control step).
  * Quaternions are w, x, y, z (MuJoCo's order). Rotation forms are those of
    :mod:`demo.sim.geometry`: ``euler`` = extrinsic x-y-z roll, pitch, yaw about the fixed
    base axes, ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (MuJoCo ``mju_euler2Quat(..., "XYZ")``);
    ``rotvec`` = axis * angle; ``rot6d`` = first two rows of R (pytorch3d / Diffusion Policy layout).

What an action means: commands, not measurements
  * Frame t's action is the command sent at control step t. For joint representations that is
    the arm's joint position targets; for EE representations it is the *commanded* EE pose,
    ``FK(joint targets of step t)``, never the measured pose (which lags behind the command).
  * Delta representations are differences between consecutive commands. The command "before
    frame 0" is the **anchor**: the *measured* state at frame 0 (arm joint positions from
    ``sim.state``, and the EE pose FK of them). So the first delta moves from where the robot is to
    the first command, and a policy executing deltas starts from the measured pose at reset (see
    :mod:`demo.convert.adapter`). Converted stores carry the anchor per frame (constant within an
    episode) in ``info.ee_anchor`` (x, y, z, qw, qx, qy, qz, base frame) or ``info.joint_anchor``.

Gripper (the last dimension of every representation)
  * Normalised closedness in [0, 1]: **0 = fully open, 1 = fully closed**; the robot config's
    ``gripper_range = [ctrl at open, ctrl at closed]`` maps it linearly to the actuator. It is the
    same number in every representation, so conversions copy it unchanged. The sign is the one
    robosuite/robomimic and RT-1 use (positive closes). Open X-Embodiment's standardised datasets
    (Octo/OpenVLA loaders) use 1 = open: mix with them through ``1 - gripper``.

The representations
  * ``joint_pos`` [q_1 .. q_n, gripper]: arm joint position targets (rad; m for slide joints).
  * ``joint_vel`` [qd_1 .. qd_n, gripper]: ``(q_t - q_{t-1}) * fps`` (rad/s), q_{-1} = anchor.
  * ``ee_abs`` [x, y, z, <rotation>, gripper]: the commanded EE pose. ``params.rotation`` is
    ``rot6d`` (default; continuous, as Diffusion Policy recommends), ``euler``, ``rotvec`` or
    ``quat``. Euler angles are unwrapped along each episode (continuous; any 2 pi multiple decodes
    to the same rotation).
  * ``ee_delta`` [dx, dy, dz, <rotation delta>, gripper] with ``params.rotation`` (``rotvec``
    default, ``euler``, ``rot6d``) and ``params.delta_frame``:
      - ``base`` (default): ``p_t = p_{t-1} + dp``, ``R_t = R(delta) @ R_{t-1}`` (the delta
        rotation is about base axes, applied on the left);
      - ``ee``: ``p_t = p_{t-1} + R_{t-1} @ dp``, ``R_t = R_{t-1} @ R(delta)`` (delta in the previous
        commanded EE frame, applied on the right).
  * ``ee7`` = [dx, dy, dz, droll, dpitch, dyaw, gripper]: the canonical Open X-Embodiment-style
    action, ``ee_delta`` with ``rotation=euler`` and ``delta_frame=base`` fixed:
    ``p_t = p_{t-1} + (dx, dy, dz)`` and ``R_t = Rz(dyaw) Ry(dpitch) Rx(droll) @ R_{t-1}``. Per-step
    rotations are small, far from Euler's gimbal lock at |dpitch| = pi/2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.sim import geometry as rot
from demo.store import ActionSpec, FeatureSpec

GRIPPER_NAME = "gripper"
GRIPPER_UNIT = "1"
GRIPPER_MEANING = "closedness in [0, 1]: 0 = open, 1 = closed"
EE_ANCHOR_KEY = "info.ee_anchor"
JOINT_ANCHOR_KEY = "info.joint_anchor"
DELTA_FRAMES = ("base", "ee")


@dataclass(frozen=True)
class Representation:
    """One registered action representation (see the module docstring for the exact meaning)."""

    name: str
    space: str  # "joint" | "ee"
    delta: bool
    rotations: tuple[str, ...] = ()  # rotation forms it accepts (ee only)
    default_rotation: str | None = None
    fixed_delta_frame: str | None = None  # ee7 pins the delta frame
    summary: str = ""


REPRESENTATIONS: dict[str, Representation] = {
    r.name: r
    for r in (
        Representation("joint_pos", "joint", False, summary="arm joint position targets + gripper"),
        Representation("joint_vel", "joint", True, summary="arm joint velocities between commands + gripper"),
        Representation("ee_abs", "ee", False, ("rot6d", "euler", "rotvec", "quat"), "rot6d",
                       summary="absolute commanded EE pose in the base frame + gripper"),
        Representation("ee_delta", "ee", True, ("rotvec", "euler", "rot6d"), "rotvec",
                       summary="EE pose change between commands (base or EE frame) + gripper"),
        Representation("ee7", "ee", True, ("euler",), "euler", fixed_delta_frame="base",
                       summary="EE deltas dx dy dz droll dpitch dyaw + gripper, base frame (Open X-Embodiment style)"),
    )
}


def get_representation(name: str, where: object = "--to") -> Representation:
    if name not in REPRESENTATIONS:
        raise DemoError(where, f"unknown action representation {name!r} (known: {', '.join(REPRESENTATIONS)})")
    return REPRESENTATIONS[name]


@dataclass(frozen=True)
class ActionFormat:
    """A representation with its options resolved: everything needed to read or write its arrays."""

    rep: Representation
    joint_names: tuple[str, ...] = ()
    joint_units: tuple[str, ...] = ()
    rotation: str | None = None
    delta_frame: str = "base"

    @property
    def name(self) -> str:
        return self.rep.name

    @property
    def rot_dim(self) -> int:
        return rot.ROTATION_DIMS[self.rotation] if self.rotation else 0

    @property
    def dim(self) -> int:
        if self.rep.space == "joint":
            return len(self.joint_names) + 1
        return 3 + self.rot_dim + 1

    def names_units(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        if self.rep.space == "joint":
            if self.rep.delta:
                return (*(f"{j}.vel" for j in self.joint_names), GRIPPER_NAME), (
                    *(f"{u}/s" for u in self.joint_units), GRIPPER_UNIT)
            return (*self.joint_names, GRIPPER_NAME), (*self.joint_units, GRIPPER_UNIT)
        assert self.rotation is not None
        rot_units = ("rad",) * 3 if self.rotation in ("euler", "rotvec") else ("1",) * self.rot_dim
        if self.rep.delta:
            names = ("dx", "dy", "dz", *(f"d{n}" for n in rot.ROTATION_NAMES[self.rotation]), GRIPPER_NAME)
        else:
            names = ("x", "y", "z", *rot.ROTATION_NAMES[self.rotation], GRIPPER_NAME)
        return names, ("m", "m", "m", *rot_units, GRIPPER_UNIT)

    @property
    def anchor_key(self) -> str | None:
        if not self.rep.delta:
            return None
        return JOINT_ANCHOR_KEY if self.rep.space == "joint" else EE_ANCHOR_KEY

    def anchor_feature(self) -> FeatureSpec | None:
        if self.anchor_key == EE_ANCHOR_KEY:
            return FeatureSpec((7,), "float64", "commanded EE pose before frame 0 (measured at frame 0): "
                               "position + quaternion wxyz, base frame", "m,1",
                               ("x", "y", "z", "qw", "qx", "qy", "qz"))
        if self.anchor_key == JOINT_ANCHOR_KEY:
            return FeatureSpec((len(self.joint_names),), "float64", "arm joint positions at frame 0 "
                               "(the command before frame 0)", ",".join(self.joint_units), self.joint_names)
        return None

    def spec(self) -> ActionSpec:
        """The store metadata for this format."""
        names, units = self.names_units()
        params: dict[str, Any] = {"gripper": GRIPPER_MEANING}
        if self.rep.space == "ee":
            params.update(rotation=self.rotation, ee_pose="commanded")
            if self.rep.delta:
                params["delta_frame"] = self.delta_frame
        else:
            params["arm_joints"] = list(self.joint_names)
        if self.anchor_key:
            params["anchor"] = self.anchor_key
        frame = "base" if self.rep.space == "ee" else "joint"
        return ActionSpec(self.name, names, units, frame=frame, description=self.rep.summary, params=params)


def make_format(
    name: str,
    *,
    joint_names: Sequence[str] = (),
    joint_units: Sequence[str] | None = None,
    rotation: str | None = None,
    delta_frame: str | None = None,
    where: object = "--to",
) -> ActionFormat:
    """Resolve a representation name and options, failing clearly on a bad combination."""
    rep = get_representation(name, where)
    if rep.space == "joint":
        if rotation:
            raise DemoError(where, f"{name} has no rotation (--rotation applies to ee_abs and ee_delta)")
        if not joint_names:
            raise DemoError(where, f"{name} needs the robot's arm joint names")
        units = tuple(joint_units) if joint_units else ("rad",) * len(joint_names)
        return ActionFormat(rep, tuple(joint_names), units)
    form = rotation or rep.default_rotation
    if form not in rep.rotations:
        raise DemoError(where, f"{name} takes rotation {' | '.join(rep.rotations)}, not {form!r}")
    frame = rep.fixed_delta_frame or delta_frame or "base"
    if rep.fixed_delta_frame and delta_frame not in (None, rep.fixed_delta_frame):
        raise DemoError(where, f"{name} deltas are always in the {rep.fixed_delta_frame} frame")
    if frame not in DELTA_FRAMES:
        raise DemoError(where, f"delta frame must be one of {', '.join(DELTA_FRAMES)}, not {frame!r}")
    return ActionFormat(rep, (), (), form, frame)  # EE formats do not depend on the arm's joints


def parse_spec(spec: ActionSpec, where: object, joint_names: Sequence[str] = ()) -> ActionFormat:
    """The :class:`ActionFormat` a store's ``ActionSpec`` describes (checks its dimension)."""
    rep = get_representation(spec.name, where)
    if rep.space == "joint":
        n = spec.dim - 1
        if joint_names and len(joint_names) != n:
            raise DemoError(where, f"action {spec.name} has {n} joints but the robot has {len(joint_names)} arm joints")
        listed = tuple(spec.params.get("arm_joints") or ())
        if joint_names:
            names = tuple(joint_names)
        elif len(listed) == n:
            names = listed
        else:
            names = tuple(x.removesuffix(".vel") for x in spec.names[:n])
        units = tuple(u.removesuffix("/s") for u in spec.units[:n]) if rep.delta else tuple(spec.units[:n])
        fmt = ActionFormat(rep, names, units)
    else:
        fmt = make_format(spec.name, joint_names=joint_names, rotation=spec.params.get("rotation"),
                          delta_frame=spec.params.get("delta_frame"), where=where)
    if fmt.dim != spec.dim:
        raise DemoError(where, f"action {spec.name} should have {fmt.dim} dimensions, the metadata says {spec.dim}")
    return fmt


# ---------------------------------------------------------------------------------------------- tracks
@dataclass
class JointTrack:
    """Commanded arm joint targets ``q`` [N, n] and gripper closedness [N]."""

    q: np.ndarray
    gripper: np.ndarray


@dataclass
class PoseTrack:
    """Commanded EE poses (base frame) ``pos`` [N, 3], ``rot`` [N, 3, 3] and gripper [N]."""

    pos: np.ndarray
    rot: np.ndarray
    gripper: np.ndarray


@dataclass
class Anchor:
    """The command before each episode's frame 0 (see the module docstring), one row per episode:
    arm joints ``q`` [E, n] and/or EE pose ``pos`` [E, 3], ``rot`` [E, 3, 3]."""

    q: np.ndarray | None = None
    pos: np.ndarray | None = None
    rot: np.ndarray | None = None

    def pose7(self) -> np.ndarray:
        """[E, 7]: position + quaternion wxyz (the ``info.ee_anchor`` layout)."""
        assert self.pos is not None and self.rot is not None
        return np.concatenate([self.pos, rot.from_mat(self.rot, "quat")], axis=-1)

    @classmethod
    def from_pose7(cls, pose: np.ndarray, q: np.ndarray | None = None) -> "Anchor":
        pose = np.atleast_2d(np.asarray(pose, dtype=np.float64))
        return cls(q=q, pos=pose[:, :3].copy(), rot=rot.to_mat(pose[:, 3:7], "quat"))


class Segments:
    """Episode boundaries of concatenated frames: ``ends`` are cumulative (as in the store)."""

    def __init__(self, ends: Sequence[int] | np.ndarray):
        self.ends = np.asarray(ends, dtype=np.int64).reshape(-1)
        self.starts = np.concatenate([[0], self.ends[:-1]]).astype(np.int64)
        self.lengths = self.ends - self.starts
        self.episode_of = np.repeat(np.arange(len(self.ends)), self.lengths)

    @classmethod
    def single(cls, length: int) -> "Segments":
        return cls([length])

    def previous(self, x: np.ndarray, first: np.ndarray) -> np.ndarray:
        """``x`` shifted one frame later within each episode; each episode's first row = ``first[e]``."""
        out = np.empty_like(x)
        out[1:] = x[:-1]
        out[self.starts] = first
        return out

    def cumsum(self, x: np.ndarray) -> np.ndarray:
        """Cumulative sum along axis 0 that restarts at every episode."""
        cs = np.cumsum(x, axis=0)
        before = np.concatenate([np.zeros((1, *x.shape[1:])), cs[self.ends[:-1] - 1]])
        return cs - np.repeat(before, self.lengths, axis=0)


def check_actions(action: np.ndarray, fmt: ActionFormat, where: object) -> np.ndarray:
    """float64 copy of ``action`` [N, dim], or a DemoError for a wrong shape or a non-finite value."""
    a = np.asarray(action, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != fmt.dim:
        raise DemoError(where, f"{fmt.name} actions must be [T, {fmt.dim}], got shape {tuple(np.shape(action))}")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise DemoError(where, f"non-finite action (NaN or inf) at frame {int(np.flatnonzero(bad)[0])}")
    return a


def decode(fmt: ActionFormat, action: np.ndarray, fps: float, anchor: Anchor | None = None,
           segments: Segments | None = None, where: object = "action") -> JointTrack | PoseTrack:
    """Actions [N, dim] (episodes concatenated as ``segments``; default one episode) -> commands."""
    a = check_actions(action, fmt, where)
    seg = segments or Segments.single(len(a))
    grip = a[:, -1].copy()
    if fmt.rep.space == "joint":
        q = a[:, :-1]
        if fmt.rep.delta:
            q0 = _need(anchor, "q", fmt, where)
            q = np.repeat(q0, seg.lengths, axis=0) + seg.cumsum(q / fps)
        return JointTrack(q.copy(), grip)
    try:
        R = rot.to_mat(a[:, 3:3 + fmt.rot_dim], fmt.rotation or "")
    except ValueError as exc:
        raise DemoError(where, f"{fmt.name}: {exc}") from None
    if not fmt.rep.delta:
        return PoseTrack(a[:, :3].copy(), R, grip)
    p0, R0 = _need(anchor, "pos", fmt, where), _need(anchor, "rot", fmt, where)
    dp = a[:, :3]
    left = fmt.delta_frame == "base"
    Rs = compose_prefix(R, R0, seg, left=left)
    if not left:
        dp = np.einsum("tij,tj->ti", seg.previous(Rs, R0), dp)
    return PoseTrack(np.repeat(p0, seg.lengths, axis=0) + seg.cumsum(dp), Rs, grip)


def encode(fmt: ActionFormat, track: JointTrack | PoseTrack, fps: float, anchor: Anchor | None = None,
           segments: Segments | None = None, where: object = "action") -> np.ndarray:
    """Commands -> actions [N, dim] (float64) in ``fmt``."""
    g = np.asarray(track.gripper, dtype=np.float64)[:, None]
    seg = segments or Segments.single(len(g))
    if fmt.rep.space == "joint":
        if not isinstance(track, JointTrack):
            raise TypeError("joint representations encode a JointTrack")
        q = track.q
        if fmt.rep.delta:
            q = (q - seg.previous(q, _need(anchor, "q", fmt, where))) * fps
        return np.concatenate([q, g], axis=1)
    if not isinstance(track, PoseTrack):
        raise TypeError("EE representations encode a PoseTrack")
    if not fmt.rep.delta:
        body = rot.from_mat(track.rot, fmt.rotation or "")
        if fmt.rotation == "euler":
            body = _unwrap(body, seg)
        return np.concatenate([track.pos, body, g], axis=1)
    p_prev = seg.previous(track.pos, _need(anchor, "pos", fmt, where))
    R_prev = seg.previous(track.rot, _need(anchor, "rot", fmt, where))
    dp = track.pos - p_prev
    if fmt.delta_frame == "base":
        Rd = track.rot @ np.swapaxes(R_prev, 1, 2)
    else:
        dp = np.einsum("tji,tj->ti", R_prev, dp)
        Rd = np.swapaxes(R_prev, 1, 2) @ track.rot
    return np.concatenate([dp, rot.from_mat(Rd, fmt.rotation or ""), g], axis=1)


def compose_prefix(Rd: np.ndarray, R0: np.ndarray, segments: Segments | None = None, *, left: bool) -> np.ndarray:
    """Every partial composition of per-step rotations ``Rd`` [N, 3, 3], restarting at each episode
    from its ``R0[e]``: ``left``: ``R_t = Rd_t @ R_{t-1}`` (base-frame deltas), else
    ``R_t = R_{t-1} @ Rd_t``. A segmented log-depth (Hillis-Steele) scan: ~log2(longest episode)
    batched products for the whole store instead of a loop over frames.
    """
    P = np.array(Rd, dtype=np.float64)
    seg = segments or Segments.single(len(P))
    R0 = np.asarray(R0, dtype=np.float64).reshape(-1, 3, 3)
    first = seg.starts[seg.episode_of]  # per frame: index of its episode's first frame
    k = 1
    longest = int(seg.lengths.max(initial=0))
    while k < longest:
        i = np.flatnonzero(np.arange(len(P)) - k >= first)
        P[i] = (P[i] @ P[i - k]) if left else (P[i - k] @ P[i])
        k *= 2
    R0f = R0[seg.episode_of]
    return P @ R0f if left else R0f @ P


def _unwrap(angles: np.ndarray, seg: Segments) -> np.ndarray:
    """np.unwrap along time within each episode (every episode starts in (-pi, pi])."""
    d = np.diff(angles, axis=0, prepend=angles[:1])
    d[seg.starts] = 0.0
    step = np.round(d / (2 * np.pi)) * (2 * np.pi)
    return angles - seg.cumsum(step)


def _need(anchor: Anchor | None, attr: str, fmt: ActionFormat, where: object) -> np.ndarray:
    value = getattr(anchor, attr) if anchor is not None else None
    if value is None:
        what = "initial joint positions" if attr == "q" else "initial EE pose"
        raise DemoError(where, f"{fmt.name} is relative to the previous command and needs the episode's {what} "
                               "(sim.state, or an anchor feature)")
    value = np.asarray(value, dtype=np.float64)
    return value[None] if value.ndim == (2 if attr == "rot" else 1) else value
