"""`pick`: grasp a cube from the table and lift it.

Reset: the cube (edge ``cube_size``, 80 g) lies flat at a random position in front of the robot
(x 0.40..0.62 m, |y| <= 0.20 m, base frame) with a random heading. Success: the cube's centre is
``lift_height`` above its resting height. Observations: ``obs.object_pos`` [1,3] (m),
``obs.object_quat`` [1,4] (wxyz, w >= 0), base frame.

Expert: approach above the cube, descend, close, lift (see :mod:`demo.sim.grasp`); every phase
is read off the state, so it recovers from any state (cube dropped, knocked, moved).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import canonical_f32, down_quat, yaw_of
from demo.sim.grasp import BoxState, approach_and_grasp
from demo.sim.scene import BaseFrame, add_box_body
from demo.sim.task import Expert, ExpertParams, Task, place_free_body
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env

CUBE_MASS = 0.08  # kg


@dataclasses.dataclass
class PickParams(ExpertParams):
    approach_height: float = 0.10  # m above the grasp point where the descent starts
    grasp_depth: float = 0.0  # m, grasp point above (+) / below (-) the cube centre
    grasp_yaw: float = 0.0  # rad added to the face-aligned gripper heading
    lift_to: float = 0.16  # m the expert lifts the cube above its resting height


class PickExpert(Expert):
    Params = PickParams
    VARIATIONS = {"approach_height": (0.05, 0.15), "grasp_depth": (-0.004, 0.006), "grasp_yaw": (-0.2, 0.2)}
    p: PickParams

    def act(self, env: "Env") -> np.ndarray:
        task: Pick = env.task  # type: ignore[assignment]
        box = task.box(env)
        p = self.p
        ee = env.ee_pose()
        a = approach_and_grasp(self, env, box, box.pos[2] + p.grasp_depth + p.approach_height, p.grasp_depth, p.grasp_yaw, ee=ee)
        if a is not None:
            return a
        ee_pos, ee_quat = ee
        lift = np.array([ee_pos[0], ee_pos[1], task.half + p.lift_to + p.grasp_depth])
        return self.move(env, lift, down_quat(yaw_of(ee_quat)), 1.0, ee=ee)  # keep the grasp heading


class Pick(Task):
    name = "pick"
    defaults = {"cube_size": 0.04, "lift_height": 0.10}
    expert_class = PickExpert

    def __init__(self, **options):
        super().__init__(**options)
        self.half = float(self.options["cube_size"]) / 2
        if not 0.01 <= self.half <= 0.035:
            raise DemoError("pick", f"cube_size must be within 0.02..0.07 m, got {self.options['cube_size']}")

    @property
    def horizon(self) -> int:
        return 160

    def build(self, spec: mujoco.MjSpec, base: BaseFrame) -> None:
        add_box_body(spec, base, "cube", [self.half] * 3, [0.85, 0.2, 0.2, 1.0], CUBE_MASS)

    def bind(self, env: "Env") -> None:
        m = env.model
        self.body = m.body("cube").id
        self.joint = m.joint("cube_joint").id
        self.mask = np.zeros(m.ngeom, dtype=bool)
        self.mask[m.geom("cube").id] = True

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        x, y = rng.uniform(0.40, 0.62), rng.uniform(-0.20, 0.20)
        yaw = rng.uniform(-math.pi, math.pi)
        place_free_body(env, self.joint, np.array([x, y, self.half]), yaw)

    def box(self, env: "Env") -> BoxState:
        pos, quat = env.body_pose(self.body)
        return BoxState(pos, quat, self.half, self.mask)

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        return {
            "obs.object_pos": FeatureSpec((1, 3), "float32", "cube centre, base frame", "m", ("x", "y", "z")),
            "obs.object_quat": FeatureSpec((1, 4), "float32", "cube orientation, base frame, w >= 0", "1", ("w", "x", "y", "z")),
        }

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        pos, quat = env.body_pose(self.body)
        out["obs.object_pos"] = pos.astype(np.float32)[None]
        out["obs.object_quat"] = canonical_f32(quat)[None]

    def success(self, env: "Env") -> bool:
        pos, _ = env.body_pose(self.body)
        return bool(pos[2] >= self.half + float(self.options["lift_height"]))
