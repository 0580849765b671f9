"""`push`: push a block across the table into a goal region, without grasping it.

Reset: the block (``block_size`` cube, 150 g) lies at x 0.42..0.58, |y| <= 0.12 m with a random
heading; the goal (a disc marker, mocap) is 0.10..0.20 m away in a random direction, inside
x 0.35..0.68, |y| <= 0.25. Success: the block centre is within ``goal_radius`` of the goal centre
(in the table plane). Observations: ``obs.object_pos`` [1,3], ``obs.object_quat`` [1,4],
``obs.goal_pos`` [3] (m, base frame; goal z = 0, the table top).

Expert (contact-rich, state feedback): fingers closed into a flat 4 cm pusher facing the push
direction u = (goal - block)/|goal - block|. If the pusher is low and behind the block it tracks
a point just inside the block's rear face on the line through the block centre along u (so
lateral drift and rotation are corrected every step); otherwise it hovers over to a standoff
point behind the block and descends. It backs up and lifts once the block is within ``done_tol``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import canonical_f32, down_quat, nearest_symmetric
from demo.sim.scene import BaseFrame, add_box_body, add_marker_geom, add_mocap_body
from demo.sim.task import Expert, ExpertParams, Task, place_free_body
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env

BLOCK_MASS = 0.15  # kg
PUSHER_HALF = 0.011  # m, half thickness of the closed fingers along the push direction


@dataclasses.dataclass
class PushParams(ExpertParams):
    push_height: float = 0.0  # m, TCP height relative to the block centre while pushing
    hover_height: float = 0.08  # m above the block top when moving around it
    contact_offset: float = 0.0  # m, lateral offset of the pushing point from the centre line
    push_speed: float = 0.45  # fraction of the free-space speed used while in contact
    done_tol: float = 0.015  # m, block-goal distance at which the expert stops pushing
    redo_tol: float = 0.022  # m, distance at which a pusher that has backed off pushes again


class PushExpert(Expert):
    Params = PushParams
    VARIATIONS = {"push_height": (-0.006, 0.006), "hover_height": (0.05, 0.12), "contact_offset": (-0.008, 0.008)}
    p: PushParams

    def act(self, env: "Env") -> np.ndarray:
        task: Push = env.task  # type: ignore[assignment]
        p = self.p
        b, _ = env.body_pose(task.body)
        g = task.goal(env)
        ee_pose = env.ee_pose()
        ee = ee_pose[0]
        r = g[:2] - b[:2]
        dist = math.hypot(r[0], r[1])
        u = r / dist if dist > 1e-6 else np.array([1.0, 0.0])
        n = np.array([-u[1], u[0]])
        yaw = nearest_symmetric(math.atan2(u[1], u[0]), env.home_yaw, math.pi)
        q = down_quat(yaw)
        h = task.half
        z_push = b[2] + p.push_height
        z_hover = b[2] + h + p.hover_height
        rel = ee[:2] - b[:2]
        along, lat = float(rel @ u), float(rel @ n) - p.contact_offset
        low = ee[2] < z_push + 0.02
        # Near the goal the push direction swings with every millimetre: tolerate more offset there.
        lat_tol = (0.8 if dist > 0.05 else 1.2) * h
        pushing = low and -(h + 0.05) < along < -(h + 0.004) and abs(lat) < lat_tol

        if dist < (p.done_tol if pushing else p.redo_tol):
            back = np.array([*(b[:2] - u * (h + 0.05)), z_hover])  # done: back off and lift
            return self.move(env, back, q, 1.0, ee=ee_pose)
        if pushing:
            # Aim just inside the rear face; slow down near the goal so the block does not overshoot.
            step = 0.8 * min(dist, 0.02)
            tgt = b[:2] + n * p.contact_offset - u * (h + PUSHER_HALF - step)
            slow = p.push_speed * min(1.0, max(0.3, dist / 0.05))
            return self.move(env, np.array([tgt[0], tgt[1], z_push]), q, 1.0, speed=slow, ee=ee_pose)
        stand = b[:2] + n * p.contact_offset - u * (h + PUSHER_HALF + 0.03)
        to_stand = math.hypot(ee[0] - stand[0], ee[1] - stand[1])
        descending = ee[2] < z_hover - 0.015 and to_stand < 0.03
        if to_stand < 0.012 or descending or (low and along < -(h + 0.004) and abs(lat) < h + 0.03):
            return self.move(env, np.array([stand[0], stand[1], z_push]), q, 1.0, ee=ee_pose)  # descend / re-align behind
        if ee[2] > z_hover - 0.015:
            return self.move(env, np.array([stand[0], stand[1], z_hover]), q, 1.0, ee=ee_pose)  # hover over to the standoff
        return self.move(env, np.array([ee[0], ee[1], z_hover]), q, 1.0, ee=ee_pose)  # lift clear of the block first


class Push(Task):
    name = "push"
    defaults = {"block_size": 0.05, "goal_radius": 0.03}
    expert_class = PushExpert

    def __init__(self, **options):
        super().__init__(**options)
        self.half = float(self.options["block_size"]) / 2
        if not 0.015 <= self.half <= 0.04:
            raise DemoError("push", f"block_size must be within 0.03..0.08 m, got {self.options['block_size']}")

    @property
    def horizon(self) -> int:
        return 200

    def build(self, spec: mujoco.MjSpec, base: BaseFrame) -> None:
        add_box_body(spec, base, "block", [self.half] * 3, [0.2, 0.35, 0.85, 1.0], BLOCK_MASS, friction=(0.5, 0.01, 0.001))
        goal = add_mocap_body(spec, "goal")
        r = float(self.options["goal_radius"])
        add_marker_geom(goal, mujoco.mjtGeom.mjGEOM_CYLINDER, [r, 0.0008], [0.1, 0.8, 0.2, 0.6], pos=[0, 0, 0.0008])

    def bind(self, env: "Env") -> None:
        m = env.model
        self.body = m.body("block").id
        self.joint = m.joint("block_joint").id
        self.mocap = int(m.body_mocapid[m.body("goal").id])

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        b = np.array([rng.uniform(0.42, 0.58), rng.uniform(-0.12, 0.12)])
        while True:
            ang, dist = rng.uniform(-math.pi, math.pi), rng.uniform(0.10, 0.20)
            g = b + dist * np.array([math.cos(ang), math.sin(ang)])
            if 0.35 <= g[0] <= 0.68 and abs(g[1]) <= 0.25:
                break
        place_free_body(env, self.joint, np.array([b[0], b[1], self.half]), rng.uniform(-math.pi, math.pi))
        env.set_mocap_pose(self.mocap, np.array([g[0], g[1], 0.0]))

    def goal(self, env: "Env") -> np.ndarray:
        return env.mocap_pose(self.mocap)[0]

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        return {
            "obs.object_pos": FeatureSpec((1, 3), "float32", "block centre, base frame", "m", ("x", "y", "z")),
            "obs.object_quat": FeatureSpec((1, 4), "float32", "block orientation, base frame, w >= 0", "1", ("w", "x", "y", "z")),
            "obs.goal_pos": FeatureSpec((3,), "float32", "goal region centre on the table, base frame", "m", ("x", "y", "z")),
        }

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        pos, quat = env.body_pose(self.body)
        out["obs.object_pos"] = pos.astype(np.float32)[None]
        out["obs.object_quat"] = canonical_f32(quat)[None]
        out["obs.goal_pos"] = self.goal(env).astype(np.float32)

    def success(self, env: "Env") -> bool:
        pos, _ = env.body_pose(self.body)
        g = self.goal(env)
        return bool(math.hypot(pos[0] - g[0], pos[1] - g[1]) < float(self.options["goal_radius"]) and pos[2] < self.half + 0.01)
