"""`pick`: grasp a cube from the table and lift it.

Reset: the cube (edge ``cube_size``, 80 g) lies flat at a random position in front of the robot
(x 0.40..0.62 m, |y| <= 0.20 m, base frame) with a random heading. Success: the cube's centre is
``lift_height`` above its resting height. Observations: ``obs.object_pos`` [1,3] (m),
``obs.object_quat`` [1,4] (wxyz, w >= 0), base frame.

Told in words (``colours`` 2 or 3): that many cubes, red, green and blue, at least
:data:`MIN_GAP` apart; each episode's target is drawn from its seed, and only the episode's
instruction names it ("pick up the blue cube", :attr:`Pick.instruction`; ``phrasing=held_out``
words it with templates no training episode used). Observations hold every cube, in colour order
(``[K,3]``, ``[K,4]``); success is the target's lift.

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
from demo.sim.grasp import BoxState, approach_and_grasp, geom_mask
from demo.sim.scene import BaseFrame, add_box_body
from demo.sim.task import Expert, ExpertParams, Task, place_free_body
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env

CUBE_MASS = 0.08  # kg
COLOURS = {"red": (0.85, 0.2, 0.2, 1.0), "green": (0.2, 0.7, 0.25, 1.0), "blue": (0.2, 0.35, 0.85, 1.0)}
MIN_GAP = 0.09  # m between cube centres: the open gripper (8 cm) fits between two cubes
# How an episode's instruction names its target: the templates training episodes use, and others
PHRASINGS = {
    "train": ("pick up the {} cube", "lift the {} cube", "grab the {} block"),
    "held_out": ("raise the {} block", "take the {} cube off the table"),
}


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
    defaults = {"cube_size": 0.04, "lift_height": 0.10, "colours": 0, "phrasing": "train"}
    expert_class = PickExpert
    wording_options = ("phrasing",)

    def __init__(self, **options):
        super().__init__(**options)
        self.half = float(self.options["cube_size"]) / 2
        if not 0.01 <= self.half <= 0.035:
            raise DemoError("pick", f"cube_size must be within 0.02..0.07 m, got {self.options['cube_size']}")
        self.colours = int(self.options["colours"])
        if self.colours not in (0, 2, 3):
            raise DemoError("pick", f"colours must be 0 (one red cube, no instruction), 2 or 3, got {self.colours}")
        if self.options["phrasing"] not in PHRASINGS:
            raise DemoError("pick", f"phrasing must be one of {', '.join(PHRASINGS)}, got {self.options['phrasing']!r}")
        self.names = ["cube"] if not self.colours else [f"cube_{c}" for c in list(COLOURS)[: self.colours]]
        self.target = 0  # which cube (index into names) the episode asks for
        self.template = ""  # the instruction's template, "{}" for the target's colour

    @property
    def horizon(self) -> int:
        return 160

    def build(self, spec: mujoco.MjSpec, base: BaseFrame) -> None:
        rgba = [COLOURS["red"]] if not self.colours else list(COLOURS.values())
        for name, colour in zip(self.names, rgba):
            add_box_body(spec, base, name, [self.half] * 3, list(colour), CUBE_MASS)

    def bind(self, env: "Env") -> None:
        m = env.model
        self.bodies = [m.body(name).id for name in self.names]
        self.joints = [m.joint(f"{name}_joint").id for name in self.names]
        self.masks = [geom_mask(m, name) for name in self.names]

    @property
    def body(self) -> int:
        """The target cube's body id."""
        return self.bodies[self.target]

    @property
    def joint(self) -> int:
        """The target cube's free joint."""
        return self.joints[self.target]

    @property
    def mask(self) -> np.ndarray:
        """The target cube's geoms (bool over model geoms)."""
        return self.masks[self.target]

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        placed: list[np.ndarray] = []
        for joint in self.joints:
            while True:  # the one cube of colours=0 takes its first draw, as it always did
                x, y = rng.uniform(0.40, 0.62), rng.uniform(-0.20, 0.20)
                if all(np.hypot(x - p[0], y - p[1]) >= MIN_GAP for p in placed):
                    break
            yaw = rng.uniform(-math.pi, math.pi)
            place_free_body(env, joint, np.array([x, y, self.half]), yaw)
            placed.append(np.array([x, y]))
        if self.colours:
            self.target = int(rng.integers(self.colours))
            templates = PHRASINGS[self.options["phrasing"]]
            self.template = templates[int(rng.integers(len(templates)))]
            self.instruction = self.template.format(list(COLOURS)[self.target])

    @property
    def goals(self) -> int:
        return self.colours

    def shift_goal(self, offset: int) -> None:
        if not self.colours:
            super().shift_goal(offset)
        self.target = (self.target + offset) % self.colours
        self.instruction = self.template.format(list(COLOURS)[self.target])

    def box(self, env: "Env") -> BoxState:
        pos, quat = env.body_pose(self.body)
        return BoxState(pos, quat, self.half, self.masks[self.target])

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        k = len(self.names)
        what = "cube centre" if k == 1 else f"cube centres ({', '.join(list(COLOURS)[:k])})"
        return {
            "obs.object_pos": FeatureSpec((k, 3), "float32", f"{what}, base frame", "m", ("x", "y", "z")),
            "obs.object_quat": FeatureSpec((k, 4), "float32", f"{what.replace('centre', 'orientation')}, base frame, "
                                                              "w >= 0", "1", ("w", "x", "y", "z")),
        }

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        poses = [env.body_pose(body) for body in self.bodies]
        out["obs.object_pos"] = np.stack([pos for pos, _ in poses]).astype(np.float32)
        out["obs.object_quat"] = np.stack([canonical_f32(quat) for _, quat in poses])

    def success(self, env: "Env") -> bool:
        pos, _ = env.body_pose(self.body)
        return bool(pos[2] >= self.half + float(self.options["lift_height"]))
