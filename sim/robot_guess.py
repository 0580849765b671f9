"""Reading an arm's MJCF for `demo robot init`: which joints are the arm, which actuators the gripper, where
the EE site goes. Each answer is a guess from the model's tree and geometry, with notes where it is unsure.

- **Hand**: the shallowest body with at least ``MIN_ARM_DOF`` hinge joints on its path from the world and two
  or more child subtrees holding joints (the fingers). **Arm**: the hinge joints on the hand's path (the last
  ``MAX_ARM_DOF``). **Base**: the highest jointless body above the first arm joint.
- **Gripper actuators**: those that move a finger joint. One is enough when it moves every finger (a tendon
  over the fingers, or a joint of an equality-coupled pair); else the fewest that move them all, one per
  finger (``gripper_actuators``).
- **Open and closed**: the gripper (the arm held at qpos0, no gravity) is simulated for ``SETTLE_S`` at
  each end of every gripper actuator's ctrl range (its ctrlrange, else its joint's or tendon's range). The
  command whose finger geoms spread widest is open, the narrowest closed. Simulating covers linkages
  (four-bars closed by equality constraints) as well as slides, without reading either.
- **EE site**: at the open pose, each finger's pad is the volume-weighted centre of its collision geoms within
  ``PAD_BACK`` of its fingertip (for a finger of one long geom: ``PAD_BACK`` behind the tip). The site sits at the midpoint
  of the two pads; z from the hand body's origin (the wrist) to that midpoint, y from one pad to the other;
  its pose is in the hand body's frame (m, quat wxyz). A site already on the hand at that pose is reused.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import mat_to_quat
from demo.sim.robot_model import inside_limits, position_gain

HINGE, SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
MIN_ARM_DOF, MAX_ARM_DOF = 6, 7  # the experts' IK needs a full 6-D pose: 6 or 7 hinges
SETTLE_S = 1.5  # s the gripper alone is simulated at each command (servo time constants are ~0.1 s)
HOLD_EVERY = 5  # physics steps between resets of the held arm
PAD_BACK = 0.02  # m: a pad point lies at most this far behind its fingertip
SITE_MATCH = 0.015  # m: an existing site this close to the guessed point, with matching axes, is reused
AXIS_MATCH = math.cos(math.radians(15.0))
SNAP = math.radians(5.0)  # a site rotation this close to a right-angle one is written as that one
NOISE = 5e-4  # m: a site coordinate this small is the simulation's asymmetry, written as 0
MIN_OPENING = 0.002  # m: the fingers' spread must change this much between the two ends of the command


@dataclass(frozen=True)
class ArmGuess:
    """The arm chain and the hand (body names), with notes on what is uncertain."""

    arm_joints: tuple[str, ...]
    base_body: str
    hand_body: str
    finger_roots: tuple[str, ...]  # the hand's children whose subtrees hold the finger joints
    notes: tuple[str, ...]


@dataclass(frozen=True)
class GripperGuess:
    """The gripper actuators, each one's (open, closed) ctrl, and the finger geoms at both ends (hand frame)."""

    actuators: tuple[str, ...]
    ranges: tuple[tuple[float, float], ...]
    open_boxes: list[tuple[np.ndarray, np.ndarray]]  # per finger geom: (centre [3], corners [8, 3]) in the hand frame (m)
    closed_centres: np.ndarray  # [n, 3] the same geoms' centres, closed
    opening: tuple[float, float]  # the geoms' spread (m, mean distance from their centroid) open, closed
    notes: tuple[str, ...]


@dataclass(frozen=True)
class SiteGuess:
    """The EE site: an existing site to reuse (``reuse``), else a pose in the hand body's frame."""

    pos: tuple[float, float, float]  # m, hand frame
    quat: tuple[float, float, float, float]  # wxyz, hand frame
    reuse: str | None
    notes: tuple[str, ...]


# ---------------------------------------------------------------- the kinematic tree
def _children(model: mujoco.MjModel) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {b: [] for b in range(model.nbody)}
    for b in range(1, model.nbody):
        out[int(model.body_parentid[b])].append(b)
    return out


def _joints(model: mujoco.MjModel, body: int, kinds: Sequence[int] = (HINGE, SLIDE)) -> list[int]:
    adr, num = int(model.body_jntadr[body]), int(model.body_jntnum[body])
    return [j for j in range(adr, adr + num) if int(model.jnt_type[j]) in kinds] if num > 0 else []


def _subtree(children: dict[int, list[int]], body: int) -> list[int]:
    out, todo = [], [body]
    while todo:
        b = todo.pop()
        out.append(b)
        todo.extend(children[b])
    return out


def hinge_path(model: mujoco.MjModel, body: int) -> list[int]:
    """The hinge joints from the world down to ``body`` (its own included), root first."""
    chain: list[list[int]] = []
    while body > 0:
        chain.append(_joints(model, body, (HINGE,)))
        body = int(model.body_parentid[body])
    return [j for joints in reversed(chain) for j in joints]


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(model, kind, i) or ""


def _named(model: mujoco.MjModel, kind: mujoco.mjtObj, i: int, what: str, where: object) -> str:
    """The name of element ``i``; a config can only name named elements."""
    name = _name(model, kind, i)
    if not name:
        raise DemoError(where, f"the {what} (#{i}) has no name, and a robot config names it; give it a name in the MJCF")
    return name


def guess_mount(model: mujoco.MjModel) -> str:
    """The arm's flange for a separate gripper: the deepest body of the longest hinge chain (m)."""
    def depth(b: int) -> int:
        d = 0
        while b > 0:
            b, d = int(model.body_parentid[b]), d + 1
        return d

    best = max(range(1, model.nbody), key=lambda b: (len(hinge_path(model, b)), depth(b)), default=0)
    return _name(model, mujoco.mjtObj.mjOBJ_BODY, best)


def guess_arm(model: mujoco.MjModel, where: object) -> ArmGuess:
    """The hand, the arm's joints and its base (module docstring); DemoError when there is no arm or no gripper."""
    children = _children(model)
    moving = {b: bool(_joints(model, b)) for b in range(model.nbody)}
    holds_joint = {b: any(moving[d] for d in _subtree(children, b)) for b in range(model.nbody)}
    hands = []
    for b in range(1, model.nbody):
        path = hinge_path(model, b)
        roots = [c for c in children[b] if holds_joint[c]]
        if len(path) >= MIN_ARM_DOF and len(roots) >= 2:
            hands.append((len(path), b, roots))
    if not hands:
        longest = max((hinge_path(model, b) for b in range(1, model.nbody)), key=len, default=[])
        if len(longest) < MIN_ARM_DOF:
            names = ", ".join(_name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}" for j in longest) or "none"
            raise DemoError(where, f"found no arm: its longest serial chain of hinge joints from the base has {len(longest)} "
                                   f"({names}); an arm for demo has {MIN_ARM_DOF} or {MAX_ARM_DOF}")
        end = int(model.jnt_bodyid[longest[-1]])
        raise DemoError(where, f"found no gripper: no body below its {len(longest)}-hinge chain (ending at body "
                               f"'{_name(model, mujoco.mjtObj.mjOBJ_BODY, end)}') carries two fingers with joints; attach "
                               "a parallel gripper's MJCF with --gripper GRIPPER_MJCF [--mount BODY]")
    hands.sort(key=lambda h: h[0])
    n_path, hand, roots = hands[0]
    notes = []
    others = [h for h in hands[1:] if h[0] == n_path]
    if others:
        notes.append(f"guessed: {len(others) + 1} bodies look like hands; took "
                     f"'{_name(model, mujoco.mjtObj.mjOBJ_BODY, hand)}' (the first)")
    path = hinge_path(model, hand)
    if len(path) > MAX_ARM_DOF:
        dropped = ", ".join(_name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in path[:-MAX_ARM_DOF])
        notes.append(f"guessed: the path to the hand has {len(path)} hinges; the arm is the last {MAX_ARM_DOF} "
                     f"(not {dropped}, which demo leaves undriven)")
        path = path[-MAX_ARM_DOF:]
    arm = tuple(_named(model, mujoco.mjtObj.mjOBJ_JOINT, j, "arm joint", where) for j in path)
    base = int(model.body_parentid[int(model.jnt_bodyid[path[0]])])
    while base > 0 and not moving[base] and int(model.body_parentid[base]) > 0 and not moving[int(model.body_parentid[base])]:
        base = int(model.body_parentid[base])
    if base == 0:
        base = int(model.jnt_bodyid[path[0]])
        notes.append("guessed: the first arm joint's body hangs from the world; it is the base body")
    elif moving[base]:
        notes.append(f"guessed: the base body '{_name(model, mujoco.mjtObj.mjOBJ_BODY, base)}' has joints demo does not drive")
    slides = [j for b in _ancestors(model, hand) for j in _joints(model, b, (SLIDE,))]
    if slides:
        notes.append("guessed: slide joints on the arm's path (" + ", ".join(_name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in slides)
                     + ") are not arm joints; demo leaves them undriven")
    return ArmGuess(
        arm_joints=arm,
        base_body=_named(model, mujoco.mjtObj.mjOBJ_BODY, base, "base body", where),
        hand_body=_named(model, mujoco.mjtObj.mjOBJ_BODY, hand, "hand body (the fingers' parent)", where),
        finger_roots=tuple(_name(model, mujoco.mjtObj.mjOBJ_BODY, r) or f"#{r}" for r in roots),
        notes=tuple(notes),
    )


def _ancestors(model: mujoco.MjModel, body: int) -> list[int]:
    out = []
    while body > 0:
        out.append(body)
        body = int(model.body_parentid[body])
    return out


def _finger_of(model: mujoco.MjModel, body: int, hand: int) -> int | None:
    """The child of ``hand`` whose subtree holds ``body`` (None: not below the hand)."""
    while body > 0:
        parent = int(model.body_parentid[body])
        if parent == hand:
            return body
        body = parent
    return None


def _moved_dofs(model: mujoco.MjModel, data: mujoco.MjData, act: int) -> list[int]:
    start, n = int(data.moment_rowadr[act]), int(data.moment_rownnz[act])
    return [int(d) for d, v in zip(data.moment_colind[start:start + n], data.actuator_moment[start:start + n]) if v != 0]


def _tendon_joints(model: mujoco.MjModel, tendon: int) -> list[int]:
    adr, num = int(model.tendon_adr[tendon]), int(model.tendon_num[tendon])
    return [int(model.wrap_objid[w]) for w in range(adr, adr + num) if int(model.wrap_type[w]) == int(mujoco.mjtWrap.mjWRAP_JOINT)]


def _coupled(model: mujoco.MjModel, hand: int) -> dict[int, int]:
    """Finger roots joined by an active equality constraint -> a representative root (union-find)."""
    parent: dict[int, int] = {}

    def find(r: int) -> int:
        while parent.setdefault(r, r) != r:
            r = parent[r]
        return r

    def bodies_of(e: int, obj: int) -> list[int]:
        kind = int(model.eq_type[e])
        if kind == int(mujoco.mjtEq.mjEQ_JOINT):
            return [int(model.jnt_bodyid[obj])]
        if kind == int(mujoco.mjtEq.mjEQ_TENDON):
            return [int(model.jnt_bodyid[j]) for j in _tendon_joints(model, obj)]
        if kind in (int(mujoco.mjtEq.mjEQ_CONNECT), int(mujoco.mjtEq.mjEQ_WELD)):
            site = int(model.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE)
            return [int(model.site_bodyid[obj]) if site else obj]
        return []

    for e in range(model.neq):
        if not model.eq_active0[e]:
            continue
        ends = [int(model.eq_obj1id[e]), int(model.eq_obj2id[e])]
        bodies = [b for obj in ends if obj >= 0 for b in bodies_of(e, obj)]
        roots = {r for r in (_finger_of(model, b, hand) for b in bodies) if r is not None}
        for a, b in itertools.pairwise(sorted(roots)):
            parent[find(a)] = find(b)
    return {r: find(r) for r in list(parent)}


def gripper_actuators(model: mujoco.MjModel, arm: ArmGuess, where: object) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(the gripper actuators' names, notes): the fewest actuators that move every finger (module docstring)."""
    hand = model.body(arm.hand_body).id
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    arm_dofs = {int(model.jnt_dofadr[model.joint(j).id]) for j in arm.arm_joints}
    group = _coupled(model, hand)
    reach: dict[int, set[int]] = {}  # actuator -> the finger groups it moves
    for a in range(model.nu):
        dofs = _moved_dofs(model, data, a)
        if not dofs or arm_dofs & set(dofs):
            continue
        roots = {r for r in (_finger_of(model, int(model.dof_bodyid[d]), hand) for d in dofs) if r is not None}
        if roots:
            reach[a] = {group.get(r, r) for r in roots}
    fingers = [model.body(n).id for n in arm.finger_roots if not n.startswith("#")]
    joints = sorted({_name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for b in range(model.nbody)
                     if _finger_of(model, b, hand) is not None for j in _joints(model, b)})
    if not reach:
        raise DemoError(where, f"no actuator moves the gripper's finger joints ({', '.join(joints)}); give one a <position> "
                               "actuator in the MJCF (one on a finger joint, a tendon over both, or one per finger)")
    covered = set().union(*reach.values())
    chosen: list[int] = []
    left = set(covered)
    while left:  # greedy cover: one actuator when one moves every finger, else one per finger
        best = max(reach, key=lambda a: (len(reach[a] & left), -a))
        chosen.append(best)
        left -= reach[best]
    names = tuple(_named(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a, "gripper actuator", where) for a in chosen)
    notes = []
    all_groups = {group.get(f, f) for f in fingers}
    idle = sorted(_name(model, mujoco.mjtObj.mjOBJ_BODY, f) for f in fingers if group.get(f, f) not in covered)
    if idle:
        notes.append(f"guessed: no actuator moves finger bodies {', '.join(idle)} (passive, or coupled by springs); "
                     "check that the gripper closes on both sides")
    if len(covered) < 2 <= len(all_groups):
        notes.append(f"guessed: '{names[0]}' moves one finger only; check gripper_actuator")
    if len(names) > 1:
        notes.append(f"guessed: one actuator per finger ({', '.join(names)}), as no one of them moves every finger")
    return names, tuple(notes)


# ---------------------------------------------------------------- open and closed, by simulating the gripper
def _ctrl_ends(model: mujoco.MjModel, act: int, name: str, where: object) -> tuple[float, float]:
    """The two ends of an actuator's command: its ctrlrange, else the ctrl that reaches the ends of its
    joint's (or fixed tendon's) range through the servo's gain (``position_gain``)."""
    if model.actuator_ctrllimited[act]:
        lo, hi = (float(v) for v in model.actuator_ctrlrange[act])
        return lo, hi
    trn, target = int(model.actuator_trntype[act]), int(model.actuator_trnid[act, 0])
    gear = float(model.actuator_gear[act, 0])
    if trn == int(mujoco.mjtTrn.mjTRN_JOINT) and model.jnt_limited[target]:
        lengths = [gear * float(v) for v in model.jnt_range[target]]
    elif trn == int(mujoco.mjtTrn.mjTRN_TENDON) and model.tendon_limited[target]:
        lengths = [gear * float(v) for v in model.tendon_range[target]]
    elif trn == int(mujoco.mjtTrn.mjTRN_TENDON) and all(model.jnt_limited[j] for j in _tendon_joints(model, target)):
        adr, num = int(model.tendon_adr[target]), int(model.tendon_num[target])
        lo = hi = 0.0
        for w in range(adr, adr + num):
            coef, rng = float(model.wrap_prm[w]), model.jnt_range[int(model.wrap_objid[w])]
            ends = sorted(coef * float(v) for v in rng)
            lo, hi = lo + ends[0], hi + ends[1]
        lengths = [gear * lo, gear * hi]
    else:
        raise DemoError(where, f"gripper actuator '{name}' has no ctrlrange and drives nothing with a range; give it a "
                               "ctrlrange in the MJCF (or write gripper_range by hand)")
    scale, offset = position_gain(model, act, name, where)
    lo, hi = sorted((length - offset) / scale for length in lengths)
    return lo, hi


def _zero_gravity(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """The robot compiled without gravity (the arm is held in place while the gripper moves)."""
    g = spec.copy()
    g.option.gravity = [0.0, 0.0, 0.0]
    return g.compile()


def _finger_geoms(model: mujoco.MjModel, hand: int) -> list[int]:
    """Geoms that move with the fingers (below a joint under the hand): collision geoms, else all of them."""
    moving = [b for b in range(model.nbody) if _finger_of(model, b, hand) is not None
              and any(_joints(model, a) for a in _ancestors(model, b) if _finger_of(model, a, hand) is not None)]
    geoms = [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in moving]
    colliding = [g for g in geoms if model.geom_contype[g] or model.geom_conaffinity[g]]
    return colliding or geoms


def _boxes(model: mujoco.MjModel, data: mujoco.MjData, geoms: list[int], hand: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each geom's bounding-box centre and corners, in the hand body's frame (m)."""
    rot, origin = data.xmat[hand].reshape(3, 3), data.xpos[hand]
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    out = []
    for g in geoms:
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        local = centre + signs * half  # the box in the geom's frame
        xmat = data.geom_xmat[g].reshape(3, 3)
        world_c, world_k = data.geom_xpos[g] + xmat @ centre, data.geom_xpos[g] + local @ xmat.T
        out.append((rot.T @ (world_c - origin), (world_k - origin) @ rot))
    return out


def _spread(centres: np.ndarray) -> float:
    return float(np.mean(np.linalg.norm(centres - centres.mean(axis=0), axis=1)))


def simulate_gripper(spec: mujoco.MjSpec, arm: ArmGuess, actuators: Sequence[str], where: object) -> GripperGuess:
    """Each gripper actuator's (open, closed) ctrl, found by simulating the gripper alone at every end of
    every actuator's command; ``spec`` is the robot with its PD layer (every gripper actuator a servo)."""
    model = _zero_gravity(spec)
    hand = model.body(arm.hand_body).id
    acts = [model.actuator(n).id for n in actuators]
    ends = [_ctrl_ends(model, a, n, where) for a, n in zip(acts, actuators)]
    geoms = _finger_geoms(model, hand)
    qadr = [int(model.jnt_qposadr[model.joint(j).id]) for j in arm.arm_joints]
    dadr = [int(model.jnt_dofadr[model.joint(j).id]) for j in arm.arm_joints]
    data = mujoco.MjData(model)
    steps = int(math.ceil(SETTLE_S / model.opt.timestep / HOLD_EVERY))
    results = []
    start = inside_limits(model, model.qpos0)
    for combo in itertools.product(*ends):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = start
        data.ctrl[acts] = combo
        for _ in range(steps):  # the arm held at qpos0: its joints kept (deleting them would weld the hand to the world,
            mujoco.mj_step(model, data, HOLD_EVERY)  # and MuJoCo filters no contact with the world: hand and fingers would collide)
            data.qpos[qadr] = model.qpos0[qadr]
            data.qvel[dadr] = 0.0
        mujoco.mj_kinematics(model, data)
        boxes = _boxes(model, data, geoms, hand)
        results.append((_spread(np.array([c for c, _ in boxes])), combo, boxes))
    open_, closed = max(results, key=lambda r: r[0]), min(results, key=lambda r: r[0])
    if open_[0] - closed[0] < MIN_OPENING:
        raise DemoError(where, f"the gripper actuator(s) {', '.join(actuators)} do not move the fingers apart: commanded from "
                               f"end to end the fingers' spread changes by {1000 * (open_[0] - closed[0]):.1f} mm")
    stuck = [n for n, o, c in zip(actuators, open_[1], closed[1]) if o == c]
    if stuck:  # widest and narrowest at the same command: that actuator's finger does not move (blocked, or passive)
        raise DemoError(where, f"gripper actuator(s) {', '.join(stuck)} move no finger in simulation (the other fingers do): "
                               "a finger blocked by the arm's geometry at the mount, or a linkage the wizard cannot drive; "
                               "check --mount, or write gripper_actuator(s) and gripper_range by hand")
    notes = []
    if open_[0] - closed[0] < 0.01:
        notes.append(f"guessed: the fingers close by {1000 * (open_[0] - closed[0]):.0f} mm only; check gripper_range")
    return GripperGuess(
        actuators=tuple(actuators),
        ranges=tuple((float(o), float(c)) for o, c in zip(open_[1], closed[1])),
        open_boxes=open_[2],
        closed_centres=np.array([c for c, _ in closed[2]]),
        opening=(open_[0], closed[0]),
        notes=tuple(notes),
    )


# ---------------------------------------------------------------- the EE site
def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else v


def _pad(boxes: list[tuple[np.ndarray, np.ndarray]], z: np.ndarray) -> np.ndarray:
    """A finger's pad point: the volume-weighted centre of its geoms within PAD_BACK of the fingertip along ``z``
    (a pad of several boxes); a finger of one long geom gets the point PAD_BACK behind its tip."""
    tip = max(float(np.max(k @ z)) for _, k in boxes)
    near = [(c, _volume(k)) for c, k in boxes if float(c @ z) >= tip - PAD_BACK]
    if near:
        weights = np.array([v for _, v in near]) + 1e-12
        return np.average([c for c, _ in near], axis=0, weights=weights)
    centre = max((c for c, _ in boxes), key=lambda c: float(c @ z))
    return centre + (tip - PAD_BACK - float(centre @ z)) * z


def _volume(corners: np.ndarray) -> float:
    """The volume of a box given by its 8 corners (m^3): the product of its three edge lengths."""
    edges = corners[[1, 2, 4]] - corners[0]  # itertools.product order: z, y, x vary fastest to slowest
    return float(np.prod(np.linalg.norm(edges, axis=1)))


def _snapped(rot: np.ndarray) -> np.ndarray:
    """``rot``, or the right-angle rotation within SNAP of it (a clean quaternion in the TOML)."""
    axes = np.zeros((3, 3))
    for col in range(3):
        i = int(np.argmax(np.abs(rot[:, col])))
        axes[i, col] = np.sign(rot[i, col])
    if abs(np.linalg.det(axes) - 1.0) > 1e-9:
        return rot
    cos = (np.trace(axes.T @ rot) - 1.0) / 2.0
    return axes if math.acos(max(-1.0, min(1.0, cos))) < SNAP else rot


def guess_ee_site(model: mujoco.MjModel, arm: ArmGuess, gripper: GripperGuess) -> SiteGuess:
    """The EE site between the pads at the open pose (module docstring), in the hand body's frame."""
    boxes = gripper.open_boxes
    centres = np.array([c for c, _ in boxes])
    moves = gripper.closed_centres - centres
    notes = []
    # The finger axis: the fingers' main direction of travel between open and closed.
    _, _, vt = np.linalg.svd(moves if np.abs(moves).sum() > 1e-9 else centres - centres.mean(axis=0))
    y = vt[0]
    side = (centres - centres.mean(axis=0)) @ y
    sides = [[b for b, s in zip(boxes, side) if s < 0], [b for b, s in zip(boxes, side) if s >= 0]]
    if not sides[0] or not sides[1]:
        notes.append("guessed: the fingers' geoms do not split into two sides; check ee_site_pos")
        sides = [boxes, boxes]
    z = _unit(centres.mean(axis=0) - (centres.mean(axis=0) @ y) * y)
    for _ in range(3):  # the pads depend on z, z on the pads: a few rounds settle both
        a, b = _pad(sides[0], z), _pad(sides[1], z)
        mid = (a + b) / 2
        if np.linalg.norm(b - a) > 1e-6:
            y = _unit(b - a)
        z = _unit(mid - (mid @ y) * y)
    y = _unit(y - (y @ z) * z)
    rot = np.column_stack([np.cross(y, z), y, z])
    flipped = rot * np.array([-1.0, -1.0, 1.0])  # the same gripper turned half a turn: the smaller rotation is kept
    rot = _snapped(max((rot, flipped), key=lambda r: float(np.trace(r))))
    quat = mat_to_quat(rot)
    quat = quat if quat[0] >= 0 else -quat
    pos = tuple(round(float(v), 4) + 0.0 if abs(v) >= NOISE else 0.0 for v in mid)
    reuse = None
    hand = model.body(arm.hand_body).id
    for s in range(model.nsite):  # a site reused must sit on the hand itself: the fingers hang from the site's body
        name = _name(model, mujoco.mjtObj.mjOBJ_SITE, s)
        if not name or int(model.site_bodyid[s]) != hand or np.linalg.norm(model.site_pos[s] - mid) > SITE_MATCH:
            continue
        srot = np.zeros(9)
        mujoco.mju_quat2Mat(srot, model.site_quat[s])
        srot = srot.reshape(3, 3)
        if srot[:, 2] @ rot[:, 2] > AXIS_MATCH and abs(srot[:, 1] @ rot[:, 1]) > AXIS_MATCH:
            reuse = name
            notes.append(f"reused: site '{name}' on '{arm.hand_body}' lies between the pads with z out of the gripper "
                         "and y along the fingers")
            break
        notes.append(f"site '{name}' on '{arm.hand_body}' lies between the pads too, but its axes are not z out of the "
                     "gripper and y along the fingers, so a new site is added")
    if reuse is None:
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)  # bodies fixed to the hand keep their place in its frame at any pose
        rot_hand = data.xmat[hand].reshape(3, 3)
        for s in range(model.nsite):
            body = int(model.site_bodyid[s])
            if body == hand or _finger_of(model, body, hand) is None or _joints_on_way(model, body, hand):
                continue
            off = float(np.linalg.norm(rot_hand.T @ (data.site_xpos[s] - data.xpos[hand]) - mid))
            if off < SITE_MATCH:
                notes.append(f"site '{_name(model, mujoco.mjtObj.mjOBJ_SITE, s)}' lies {1000 * off:.0f} mm from this point, on "
                             f"'{_name(model, mujoco.mjtObj.mjOBJ_BODY, body)}' beside the fingers; the EE site must be on the "
                             f"body the fingers hang from, '{arm.hand_body}'")
        notes.append("guessed: between the finger pads at the open pose, z out of the gripper (from the wrist), y along "
                     f"the fingers, on the fingers' parent body '{arm.hand_body}' (m, wxyz in its frame); check it in the "
                     "PNG (--png)")
    return SiteGuess(pos=pos, quat=tuple(float(round(v, 7)) + 0.0 for v in quat), reuse=reuse, notes=tuple(notes))  # type: ignore[arg-type]


def _joints_on_way(model: mujoco.MjModel, body: int, hand: int) -> bool:
    """Whether a joint lies between ``hand`` and ``body`` (body below it)."""
    while body > 0 and body != hand:
        if int(model.body_jntnum[body]) > 0:
            return True
        body = int(model.body_parentid[body])
    return False
