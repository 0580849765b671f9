"""`stack`: stack ``blocks`` = N cubes on a pad, cube 0 at the bottom (N = 1: place a cube on the pad).

A long-horizon task: N pick-and-place cycles, horizon ``60 + 100 N`` control steps, so success can
be plotted against horizon. ``repeat`` = K > 1 does it K times: once the stack stands on the pad with
the gripper open, the pad moves to its next spot (drawn at reset, each at least ``2 SPACING`` from the
last; the placements done and the spots are kept in ``data.userdata``, part of the state) and the
stack must be built there again; success is the K-th stack, horizon ``60 + 100 N K``. Each cycle is
the same skill from another start, so the horizon grows while the task does not get harder per step.
With ``respawn`` = 1 the cubes are also put back on the table then, at spots drawn at reset (at least
``SPACING`` from each other, from the pad's new spot and from its last one, where the hand is; random
headings): every cycle is then a whole pick-and-place from the table, as the first one is, rather than
a short move of a cube that already stands under the open hand, so a learner's chance of failing is
about the same in every cycle and its success falls with K (``repeat`` = 1 ignores it). Reset: the pad (a marker, mocap) and the N cubes (``cube_size``, 80 g
each, distinct colours, random headings) are spread over x 0.38..0.64, |y| <= 0.25 m (base frame),
at least 9 cm apart. Success: every cube i rests on the pad at level i (centre within 2 cm of the
pad axis and 1 cm of height ``(i + 1/2) cube_size``) and the gripper is open.
Observations: ``obs.object_pos`` [N,3], ``obs.object_quat`` [N,4], ``obs.goal_pos`` [3] (pad centre
on the table), base frame; and three features that the expert's decisions hinge on, which an MLP
could only compute from the others poorly (min-max normalised over the table, a centimetre is a
few thousandths of the input range):

- ``obs.object_in_ee`` [N,3]: cube centres in the EE frame, saturated to +-``NEAR`` m
  (``NEAR tanh(x / NEAR)``): when to descend and when to close are centimetre decisions in this
  frame (finger axis = y);
- ``obs.object_yaw4`` [N,2]: sin and cos of 4 (cube yaw - EE yaw): the grasp heading relative to the
  gripper's, which a cube repeats every 90 deg (the 6D form of its quaternion does not);
- ``obs.object_to_place`` [N,3]: cube centre minus its place (pad axis, level i), saturated like
  ``object_in_ee``: when to put down, when to let go, and whether the cube is done.

Without them BC from 100 demonstrations (MLP 256x256, 4000 steps) succeeded on 3% of N = 1 episodes;
with them on 70% (30 episodes each, the stepwise expert; dropping any one of the three: 20-33%).

The expert descends onto a cube and onto its place through a funnel (``funnel``, see
:func:`demo.sim.grasp.funnel_target`), turns to the face pair nearest its current heading, and
lets go of a placed cube up to 1 cm above its level: rules that are continuous functions of the
observed state where possible, so that an imitator's small errors meet labels that correct them
(the stepwise "over, then down; back up if off" rule with hysteresis left learners hovering).

Expert (state feedback): find the lowest level k whose cube is not in place. Holding cube k: carry
it over the pad above every other cube and put it down. Holding another cube: park it on a free
spot of the table. Holding nothing: if a stray cube lies on the pad, or on top of cube k, grasp it
first (to park it); else grasp cube k (see :mod:`demo.sim.grasp`). All cubes in place: open and
rise.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import canonical, quat_to_mat, yaw_of
from demo.sim.grasp import BoxState, approach_and_grasp, box_states, box_yaw, carry_and_place, geom_mask, in_hand
from demo.sim.scene import BaseFrame, add_box_body, add_marker_geom, add_mocap_body
from demo.sim.task import Expert, ExpertParams, Task, place_free_body
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env

CUBE_MASS = 0.08  # kg
MAX_BLOCKS = 6
REGION = ((0.38, 0.64), (-0.25, 0.25))  # x, y ranges (m, base frame) for the pad and the cubes
SPACING = 0.09  # m between spawn positions
COLOURS = [(0.85, 0.2, 0.2), (0.2, 0.6, 0.25), (0.2, 0.35, 0.85), (0.9, 0.75, 0.15), (0.6, 0.25, 0.75), (0.15, 0.75, 0.8)]
# Where a wrongly held cube is put down, first free one wins (base frame x, y).
NEAR = 0.05  # m: saturation of the near-field observations (object_in_ee, object_to_place)
PARKING = [(x, y) for y in (-0.28, 0.28, -0.2, 0.2) for x in (0.36, 0.46, 0.56, 0.66)]
MAX_REPEAT = 8
DONE_SLOT = 0  # repeat > 1: data.userdata[0] = stacks completed so far; [1 + 2 i : 3 + 2 i] = the pad's i-th spot (x, y)
# respawn: after the pad's spots, per later cycle c = 1..K-1 and cube j, its (x, y, yaw) at
# [respawn_slot(K) + 3 (N (c - 1) + j) : ... + 3].


@dataclasses.dataclass
class StackParams(ExpertParams):
    approach_height: float = 0.08  # m above the grasp point where the descent starts
    clearance: float = 0.03  # m between a carried cube's bottom and the tops of the others
    grasp_yaw: float = 0.0  # rad added to the face-aligned gripper heading
    grasp_depth: float = 0.0  # m, grasp point above (+) / below (-) the cube centre
    # Descend onto a cube (and onto its place) through a funnel of this slope (m per m, see
    # demo.sim.grasp.funnel_target): a continuous function of the state, which a learner can imitate
    # and which corrects its small errors. 0: "over, then down; back up if off" (stepwise, hysteresis).
    funnel: float = 3.0


class StackExpert(Expert):
    Params = StackParams
    VARIATIONS = {"approach_height": (0.05, 0.12), "clearance": (0.02, 0.06), "grasp_yaw": (-0.15, 0.15)}
    p: StackParams

    def act(self, env: "Env") -> np.ndarray:
        task: Stack = env.task  # type: ignore[assignment]
        p = self.p
        boxes = task.boxes(env)
        pad = task.goal(env)
        s = task.size
        k = task.levels_done(env, boxes, pad)
        ee = env.ee_pose()
        ee_pos, ee_quat = ee
        held = next((i for i, b in enumerate(boxes) if in_hand(env, b, ee)[1]), None)

        def top_of_others(skip: int) -> float:
            return max([b.pos[2] + s / 2 for i, b in enumerate(boxes) if i != skip], default=0.0)

        if held is not None and held <= k:
            # Cube k, or a cube already in place (k counts it) that is still in the hand: put it
            # at its level, which releases it when it is there.
            place = np.array([pad[0], pad[1], (held + 0.5) * s])
            return carry_and_place(self, env, boxes[held], place, top_of_others(held), p.clearance, funnel=p.funnel, ee=ee)
        if held is not None:
            spot = self._parking(boxes, pad, held, s)
            return carry_and_place(self, env, boxes[held], spot, top_of_others(held), p.clearance, funnel=p.funnel, ee=ee)
        if k == len(boxes):
            top = top_of_others(-1)
            return self.move(env, np.array([ee_pos[0], ee_pos[1], max(ee_pos[2], top + 0.08)]), ee_quat, 0.0, ee=ee)
        target = self._next_to_grasp(boxes, pad, k, s)
        b = boxes[target]
        approach_z = max(b.pos[2] + p.grasp_depth + p.approach_height, top_of_others(target) + 0.04)
        others = [o.pos for i, o in enumerate(boxes) if i != target] + [pad]
        a = approach_and_grasp(self, env, b, approach_z, p.grasp_depth, p.grasp_yaw, others, funnel=p.funnel, ee=ee)
        if a is None:  # held now but the contact check above just missed it: hold still
            return self.move(env, ee_pos, ee_quat, 1.0, ee=ee)
        return a

    @staticmethod
    def _next_to_grasp(boxes: list[BoxState], pad: np.ndarray, k: int, s: float) -> int:
        """Cube k, unless a stray cube sits on the pad's free levels or on top of cube k."""
        for i, b in enumerate(boxes):
            if i == k:
                continue
            on_pad = math.hypot(b.pos[0] - pad[0], b.pos[1] - pad[1]) < s * 1.2 and b.pos[2] > (k - 0.5) * s
            on_k = math.hypot(b.pos[0] - boxes[k].pos[0], b.pos[1] - boxes[k].pos[1]) < s and b.pos[2] > boxes[k].pos[2] + s / 2
            if i > k and (on_pad or on_k):
                return i
        return k

    @staticmethod
    def _parking(boxes: list[BoxState], pad: np.ndarray, held: int, s: float) -> np.ndarray:
        for x, y in PARKING:
            free = math.hypot(x - pad[0], y - pad[1]) > 2.5 * s and all(
                math.hypot(x - b.pos[0], y - b.pos[1]) > 2.5 * s for i, b in enumerate(boxes) if i != held
            )
            if free:
                return np.array([x, y, s / 2])
        return np.array([boxes[held].pos[0], boxes[held].pos[1], s / 2])


class Stack(Task):
    name = "stack"
    defaults = {"blocks": 2, "cube_size": 0.04, "repeat": 1, "respawn": 0}
    expert_class = StackExpert

    def __init__(self, **options):
        super().__init__(**options)
        self.n = self.options["blocks"] = self._count("blocks", MAX_BLOCKS)
        self.size = float(self.options["cube_size"])
        if not 0.03 <= self.size <= 0.05:
            raise DemoError("stack", f"cube_size must be within 0.03..0.05 m, got {self.size}")
        self.repeat = self._count("repeat", MAX_REPEAT)
        respawn = self.options["respawn"]
        if respawn not in (0, 1, False, True):
            raise DemoError("stack", f"respawn must be 0 or 1, got {respawn!r}")
        self.respawn = bool(respawn) and self.repeat > 1
        self._respawn_slot = DONE_SLOT + 1 + 2 * self.repeat

    def _count(self, key: str, most: int) -> int:
        """The integer option ``key``, refused outside 1..``most``."""
        try:
            n = int(self.options[key])
        except (TypeError, ValueError):
            raise DemoError("stack", f"{key} must be an integer, got {self.options[key]!r}") from None
        if not 1 <= n <= most:
            raise DemoError("stack", f"{key} must be within 1..{most}, got {n}")
        return n

    @property
    def horizon(self) -> int:
        return 60 + 100 * self.n * self.repeat

    def build(self, spec: mujoco.MjSpec, base: BaseFrame) -> None:
        h = self.size / 2
        for i in range(self.n):
            add_box_body(spec, base, f"cube{i}", [h] * 3, [*COLOURS[i], 1.0], CUBE_MASS)
        pad = add_mocap_body(spec, "pad")
        add_marker_geom(pad, mujoco.mjtGeom.mjGEOM_BOX, [h + 0.01, h + 0.01, 0.0008], [0.1, 0.8, 0.2, 0.6], pos=[0, 0, 0.0008])
        if self.repeat > 1:
            respawns = 3 * self.n * (self.repeat - 1) if self.respawn else 0
            spec.nuserdata = max(spec.nuserdata, self._respawn_slot + respawns)

    def bind(self, env: "Env") -> None:
        m = env.model
        self.bodies = [m.body(f"cube{i}").id for i in range(self.n)]
        self.joints = [m.joint(f"cube{i}_joint").id for i in range(self.n)]
        self.masks = [geom_mask(m, f"cube{i}") for i in range(self.n)]
        self.mocap = int(m.body_mocapid[m.body("pad").id])

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        spots: list[np.ndarray] = []
        while len(spots) < self.n + 1:
            p = np.array([rng.uniform(*REGION[0]), rng.uniform(*REGION[1])])
            if all(np.linalg.norm(p - q) >= SPACING for q in spots):
                spots.append(p)
        pad, cubes = spots[0], spots[1:]
        env.set_mocap_pose(self.mocap, np.array([pad[0], pad[1], 0.0]))
        for j, xy in zip(self.joints, cubes):
            place_free_body(env, j, np.array([xy[0], xy[1], self.size / 2]), rng.uniform(-math.pi, math.pi))
        if self.repeat > 1:  # drawn after everything else, so that repeat = 1 episodes stay as they were
            d, last = env.data, pad
            d.userdata[DONE_SLOT + 1 : DONE_SLOT + 3] = pad
            for i in range(1, self.repeat):
                spot = last
                while np.linalg.norm(spot - last) < 2 * SPACING:
                    spot = np.array([rng.uniform(*REGION[0]), rng.uniform(*REGION[1])])
                d.userdata[DONE_SLOT + 1 + 2 * i : DONE_SLOT + 3 + 2 * i] = last = spot
        if self.respawn:  # drawn after the pad's spots, so that the pad's stay as they were
            d = env.data
            for c in range(1, self.repeat):
                taken = [d.userdata[DONE_SLOT + 1 + 2 * i : DONE_SLOT + 3 + 2 * i].copy() for i in (c - 1, c)]
                for j in range(self.n):
                    while True:
                        p = np.array([rng.uniform(*REGION[0]), rng.uniform(*REGION[1])])
                        if all(np.linalg.norm(p - q) >= SPACING for q in taken):
                            break
                    taken.append(p)
                    at = self._respawn_slot + 3 * (self.n * (c - 1) + j)
                    d.userdata[at : at + 3] = p[0], p[1], rng.uniform(-math.pi, math.pi)

    def after_step(self, env: "Env") -> None:
        """repeat > 1: a finished stack that is not the last moves the pad to its next spot (and,
        with ``respawn``, puts the cubes back on the table at theirs)."""
        if self.repeat == 1 or not self._stacked(env):
            return
        d = env.data
        done = int(d.userdata[DONE_SLOT])
        if done < self.repeat - 1:
            d.userdata[DONE_SLOT] = done + 1
            xy = d.userdata[DONE_SLOT + 3 + 2 * done : DONE_SLOT + 5 + 2 * done]
            env.set_mocap_pose(self.mocap, np.array([xy[0], xy[1], 0.0]))
            if self.respawn:
                for j, joint in enumerate(self.joints):
                    at = self._respawn_slot + 3 * (self.n * done + j)
                    x, y, yaw = d.userdata[at : at + 3]
                    place_free_body(env, joint, np.array([x, y, self.size / 2]), float(yaw))
            mujoco.mj_forward(env.model, d)

    def goal(self, env: "Env") -> np.ndarray:
        return env.mocap_pose(self.mocap)[0]

    def boxes(self, env: "Env") -> list[BoxState]:
        return box_states(env, self.bodies, self.masks, self.size / 2)

    def levels_done(self, env: "Env", boxes: list[BoxState], pad: np.ndarray, xy_tol: float = 0.017, z_tol: float = 0.008) -> int:
        """How many cubes, from the bottom, rest at their level on the pad."""
        for i, b in enumerate(boxes):
            if math.hypot(b.pos[0] - pad[0], b.pos[1] - pad[1]) > xy_tol or abs(b.pos[2] - (i + 0.5) * self.size) > z_tol:
                return i
        return len(boxes)

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        n = self.n
        return {
            "obs.object_pos": FeatureSpec((n, 3), "float32", "cube centres (cube 0 first), base frame", "m", ("x", "y", "z")),
            "obs.object_quat": FeatureSpec((n, 4), "float32", "cube orientations, base frame, w >= 0", "1", ("w", "x", "y", "z")),
            "obs.goal_pos": FeatureSpec((3,), "float32", "pad centre on the table, base frame", "m", ("x", "y", "z")),
            "obs.object_in_ee": FeatureSpec((n, 3), "float32", f"cube centres in the EE frame, saturated: {NEAR} tanh(p / {NEAR})",
                                            "m", ("x", "y", "z")),
            "obs.object_yaw4": FeatureSpec((n, 2), "float32", "sin, cos of 4 x (cube yaw - EE yaw)", "1", ("sin", "cos")),
            "obs.object_to_place": FeatureSpec((n, 3), "float32",
                                               f"cube centre minus its place on the pad (level i), base frame, saturated: {NEAR} tanh(d / {NEAR})",
                                               "m", ("x", "y", "z")),
        }

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        pos, quat, in_ee, yaw4 = cube_features(env, self.bodies)
        pad = self.goal(env)
        places = np.array([[pad[0], pad[1], (i + 0.5) * self.size] for i in range(self.n)])
        out["obs.object_pos"] = pos.astype(np.float32)
        out["obs.object_quat"] = quat
        out["obs.goal_pos"] = pad.astype(np.float32)
        out["obs.object_in_ee"] = in_ee
        out["obs.object_yaw4"] = yaw4
        out["obs.object_to_place"] = (NEAR * np.tanh((pos - places) / NEAR)).astype(np.float32)

    def success(self, env: "Env") -> bool:
        if self.repeat > 1 and int(env.data.userdata[DONE_SLOT]) < self.repeat - 1:
            return False
        return self._stacked(env)

    def _stacked(self, env: "Env") -> bool:
        """Every cube at its level on the pad and the gripper open."""
        done = self.levels_done(env, self.boxes(env), self.goal(env), xy_tol=0.02, z_tol=0.01)
        return done == self.n and env.gripper_closedness() < 0.5


def cube_features(env: "Env", bodies: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per cube (base frame): centre ``[N,3]`` (m, float64), and as float32 its orientation ``[N,4]`` (wxyz, w >= 0),
    centre in the EE frame saturated to +-:data:`NEAR` ``[N,3]`` (m), sin and cos of 4 x its yaw relative to the EE's
    ``[N,2]``."""
    n = len(bodies)
    pos, quat = np.empty((n, 3)), np.empty((n, 4), np.float32)
    in_ee, yaw4 = np.empty((n, 3), np.float32), np.empty((n, 2), np.float32)
    ee_pos, ee_quat = env.ee_pose()
    ee_rot, ee_yaw = quat_to_mat(ee_quat), yaw_of(ee_quat)
    for i, body in enumerate(bodies):
        p, q = env.body_pose(body)
        pos[i], quat[i] = p, canonical(q)
        in_ee[i] = NEAR * np.tanh(ee_rot.T @ (p - ee_pos) / NEAR)
        d = 4.0 * (box_yaw(q) - ee_yaw)
        yaw4[i] = math.sin(d), math.cos(d)
    return pos, quat, in_ee, yaw4
