"""Grasping a box from above, as a state-feedback rule shared by the pick and stack experts.

Every decision reads the current state: the object's pose in the EE frame (is it between the
fingers?), finger contacts (is it held?), the measured gripper closedness (is the gripper closed
on nothing?) and the EE height (is it below the approach height?). Frames: base frame, EE site
z = approach axis, y = finger axis.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from demo.sim.geometry import down_quat, nearest_symmetric, quat_angle, quat_to_mat, yaw_of

if TYPE_CHECKING:
    import mujoco

    from demo.sim.env import Env
    from demo.sim.task import Expert

CLOSING = 0.15  # measured closedness above which the fingers count as closing/closed
EMPTY = 0.9  # measured closedness above which the fingers are closed on nothing
# Position error (m) within which the gripper descends / closes / releases. The open fingers leave
# ~2 cm of play around a 4 cm cube, so a noisy or drifting operator still gets there.
GRASP_TOL = 0.015
# Funnel mode (``funnel`` > 0): near the axis of the goal, the height allowed above it grows by
# ``funnel`` m per m of horizontal error, so the gripper (or the carried box) corrects sideways while
# it descends, and rises as far as it strays. Beyond FUNNEL_FAR of the axis it first clears the
# objects (vertically) and then travels over.
FUNNEL_NEAR = 0.03  # m: full sideways correction within this horizontal error
FUNNEL_FAR = 0.05  # m: no sideways correction below the travel height beyond this one
FUNNEL_DEADBAND = 0.004  # m of horizontal error at which the funnel reaches the goal height
FUNNEL_TURN = 0.3  # m of height per rad of heading error (descend once aligned)
# Within FUNNEL_SLOW of the goal the speed falls in proportion to the distance (to MIN_SPEED of
# full speed): a proportional controller there, where full-speed steps would end in a stop-and-close
# that a regressor blurs into a stall above the goal.
FUNNEL_SLOW = 0.06  # m
FUNNEL_MIN_SPEED = 0.4
FUNNEL_DROP = 0.01  # m above its resting height at which a placed box is let go


def funnel_speed(distance: float) -> float:
    """Speed factor (of the expert's full speed) at ``distance`` (m) from the goal."""
    return min(1.0, max(FUNNEL_MIN_SPEED, distance / FUNNEL_SLOW))


def _clamp01(x: float) -> float:
    return min(1.0, max(0.0, x))


def funnel_target(current: np.ndarray, goal: np.ndarray, top: float, lift: float, slope: float, angle: float = 0.0) -> np.ndarray:
    """A point to move toward that brings ``current`` (base frame) down onto ``goal`` through a funnel.

    ``top`` is the travel height (base frame z) and ``lift`` in [0, 1] how clear of the other
    objects ``current`` already is (1: free to travel sideways). The result is a continuous
    function of the state, with no hysteresis: a learner imitating it sees nearby states labelled alike.
    """
    xy_err = math.hypot(current[0] - goal[0], current[1] - goal[1])
    near = _clamp01((FUNNEL_FAR - xy_err) / (FUNNEL_FAR - FUNNEL_NEAR))
    w = max(lift, near)
    height = slope * max(0.0, xy_err - FUNNEL_DEADBAND) + FUNNEL_TURN * max(0.0, angle - 0.05)
    z = goal[2] + min(max(0.0, top - goal[2]), height)
    return np.array([current[0] + w * (goal[0] - current[0]), current[1] + w * (goal[1] - current[1]), z])


@dataclass
class BoxState:
    pos: np.ndarray  # centre, base frame (m)
    quat: np.ndarray  # wxyz, base frame
    half: float  # half edge (m)
    geom_mask: np.ndarray  # boolean over model geoms: the box's geoms


def geom_mask(model: "mujoco.MjModel", name: str) -> np.ndarray:
    """Boolean over the model's geoms, true for the geom ``name`` alone (a box's :attr:`BoxState.geom_mask`)."""
    mask = np.zeros(model.ngeom, dtype=bool)
    mask[model.geom(name).id] = True
    return mask


def box_states(env: "Env", bodies: Sequence[int], masks: Sequence[np.ndarray], half: float) -> list[BoxState]:
    """The boxes ``bodies`` (ids, with their geom masks and half edge ``half`` in m) as they are now."""
    return [BoxState(*env.body_pose(body), half, mask) for body, mask in zip(bodies, masks)]


def box_yaw(quat: np.ndarray) -> float:
    """Heading of the box's most horizontal axis (a box looks the same every 90 deg)."""
    m = quat_to_mat(quat).tolist()
    # The body axis (column) with the least vertical component, the first of equals.
    z0, z1, z2 = abs(m[2][0]), abs(m[2][1]), abs(m[2][2])
    k = 0 if z0 <= z1 and z0 <= z2 else (1 if z1 <= z2 else 2)
    return math.atan2(m[1][k], m[0][k])


def grasp_yaw(env: "Env", box: BoxState, offset: float, others: Sequence[np.ndarray] = (), reference: float | None = None) -> float:
    """Gripper heading that closes the fingers on two faces of the box.

    Of the two face pairs, the one whose finger axis points away from nearby ``others`` (base
    frame positions within 16 cm) wins, so the open fingers and the wide hand miss them; ties go
    to the heading nearest ``reference`` (default: the home heading). Of the two headings per pair
    (fingers are symmetric), the one nearest ``reference``.
    """
    ref = env.home_yaw if reference is None else reference
    base = box_yaw(box.quat) + math.pi / 2
    best, best_cost = 0.0, math.inf
    for k in range(2):
        yaw = nearest_symmetric(base + k * math.pi / 2, ref, math.pi)
        axis = (math.sin(yaw), -math.cos(yaw))  # the finger axis (EE y) in the table plane
        cost = 0.05 * abs(yaw - ref)
        for o in others:
            dx, dy = o[0] - box.pos[0], o[1] - box.pos[1]
            dist = math.hypot(dx, dy)
            if 1e-6 < dist < 0.16:
                cost += abs(axis[0] * dx + axis[1] * dy) / dist
        if cost < best_cost:
            best, best_cost = yaw, cost
    return best + offset


def in_hand(env: "Env", box: BoxState, ee: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[bool, bool]:
    """(between the fingers, held): held = between and touched by two finger bodies.
    ``ee``: ``env.ee_pose()``, when the caller has it already."""
    ee_pos, ee_quat = env.ee_pose() if ee is None else ee
    x, y, z = np.dot(quat_to_mat(ee_quat).T, box.pos - ee_pos).tolist()  # box centre in the EE frame (R^T @ d)
    between = abs(x) < 0.02 and abs(y) < box.half + 0.01 and abs(z) < 0.6 * box.half + 0.01
    return between, between and env.finger_contacts(box.geom_mask) >= 2


def approach_and_grasp(
    expert: "Expert",
    env: "Env",
    box: BoxState,
    approach_z: float,
    depth: float = 0.0,
    yaw_offset: float = 0.0,
    others: Sequence[np.ndarray] = (),
    funnel: float = 0.0,
    ee: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray | None:
    """The action that brings the open gripper above the box, down around it, and closes it.

    Returns None once the box is held (the caller decides where to carry it). ``approach_z`` is
    the height (base frame) from which the gripper descends; ``depth`` shifts the grasp point up
    (+) or down (-) from the box centre; ``others`` are positions the hand should keep clear of.
    ``funnel`` > 0 descends through a funnel of that slope (:func:`funnel_target`) instead of
    "over, then straight down; back up if off" (a stepwise rule with hysteresis). ``ee``:
    ``env.ee_pose()``, when the caller has it already.
    """
    ee = env.ee_pose() if ee is None else ee
    between, held = in_hand(env, box, ee)
    if held:
        return None
    ee_pos, ee_quat = ee
    closed = env.gripper_closedness()
    if funnel > 0:
        # The face pair nearest the current heading (a turn of at most 45 deg): a function of the
        # relative yaw alone, which the learner observes, unlike a choice that weighs the neighbours.
        q = down_quat(grasp_yaw(env, box, yaw_offset, (), reference=yaw_of(ee_quat)))
    else:
        q = down_quat(grasp_yaw(env, box, yaw_offset, others))
    grasp = box.pos + np.array([0.0, 0.0, depth])
    if between and CLOSING < closed < EMPTY:
        return expert.move(env, ee_pos, q, 1.0, ee=ee)  # fingers closing on the box: hold still
    (ex, ey, ez), (gx, gy, gz) = ee_pos.tolist(), grasp.tolist()  # scalars as floats: the same arithmetic
    xy_err = math.hypot(ex - gx, ey - gy)
    ang = quat_angle(ee_quat, q)
    z_err = ez - gz
    if between and xy_err < GRASP_TOL and abs(z_err) < GRASP_TOL and ang < 0.15:
        return expert.move(env, grasp, q, 1.0, ee=ee)  # in place: close
    pre_z = max(approach_z, gz + 0.02)
    if closed > CLOSING:
        # Closed on nothing (or the box slipped): open while backing up to the approach height.
        return expert.move(env, np.array([ex, ey, max(ez, min(pre_z, ez + 0.05))]), q, 0.0, ee=ee)
    if funnel > 0:
        lift = _clamp01((ez - (pre_z - 0.03)) / 0.03)
        speed = funnel_speed(float(np.linalg.norm(ee_pos - grasp)))
        return expert.move(env, funnel_target(ee_pos, grasp, pre_z, lift, funnel, ang), q, 0.0, speed=speed, ee=ee)
    low = ez < pre_z - 0.004  # below the approach height: descending (hysteresis)
    if xy_err < (0.025 if low else 0.02) and ang < (0.2 if low else 0.15):
        return expert.move(env, grasp, q, 0.0, ee=ee)  # above the box: descend
    if low:
        return expert.move(env, np.array([ex, ey, pre_z]), q, 0.0, ee=ee)  # clear the objects first
    return expert.move(env, np.array([gx, gy, pre_z]), q, 0.0, ee=ee)  # over to the box


def carry_and_place(
    expert: "Expert",
    env: "Env",
    box: BoxState,
    place: np.ndarray,
    others_top: float,
    clearance: float,
    drop: float = 0.004,
    funnel: float = 0.0,
    ee: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The action that carries a held box to rest its centre at ``place`` and lets go there.

    The box travels with its bottom ``clearance`` (m) above ``others_top`` (the highest top of
    the other objects, base frame z) until it is over the place; then it descends, correcting its
    position on the way (sideways moves are safe while its bottom is above ``others_top``), and the
    gripper opens once the box is within ``drop`` (m) of its resting height. The grasp offset (box
    centre vs TCP) is read from the state, so a box held off-centre still lands where it should.
    ``funnel`` > 0: the box comes down through a funnel of that slope (:func:`funnel_target`),
    travelling sideways only as far as its bottom is clear of ``others_top``. ``ee``:
    ``env.ee_pose()``, when the caller has it already.
    """
    ee = env.ee_pose() if ee is None else ee
    ee_pos, ee_quat = ee
    offset = ee_pos - box.pos  # TCP relative to the box centre, kept while carrying
    q = down_quat(yaw_of(ee_quat))  # keep the heading it was grasped with
    xy_err = math.hypot(box.pos[0] - place[0], box.pos[1] - place[1])
    carry_z = others_top + clearance + box.half
    lowered = box.pos[2] < carry_z - 0.015
    if funnel > 0:
        # Let go from up to FUNNEL_DROP above the resting height, and aim a centimetre below it (contact
        # stops the box): the downward label stays a clear step until the release, so an imitator's
        # blurred version of it does not stall just above the place.
        if box.pos[2] < place[2] + FUNNEL_DROP and xy_err < GRASP_TOL:
            return expert.move(env, ee_pos, q, 0.0, ee=ee)  # in place: open
        lift = _clamp01((box.pos[2] - box.half - others_top) / clearance)
        goal = place - np.array([0.0, 0.0, 0.01])
        target = funnel_target(box.pos, goal, carry_z, lift, funnel) + offset
        return expert.move(env, target, q, 1.0, speed=funnel_speed(float(np.linalg.norm(box.pos - place))), ee=ee)
    if xy_err < 0.02 or (lowered and xy_err < 0.03):
        if box.pos[2] < place[2] + drop and xy_err < GRASP_TOL:
            return expert.move(env, ee_pos, q, 0.0, ee=ee)  # in place: open
        target = place + offset - np.array([0.0, 0.0, 0.002])  # a little low, so contact stops it
        return expert.move(env, target, q, 1.0, speed=0.6, ee=ee)
    over_place = np.array([place[0] + offset[0], place[1] + offset[1], carry_z + offset[2]])
    if lowered and box.pos[2] - box.half > others_top + 0.005:
        over_place[2] = ee_pos[2]  # above everything already: correct sideways at this height
        return expert.move(env, over_place, q, 1.0, ee=ee)
    if lowered:
        return expert.move(env, np.array([ee_pos[0], ee_pos[1], carry_z + offset[2]]), q, 1.0, ee=ee)  # lift clear
    return expert.move(env, over_place, q, 1.0, ee=ee)
