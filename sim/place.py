"""`place`: put the cube the instruction names on the pad it names ("put the green cube on the red pad").

Three cubes (red, green, blue; edge ``cube_size``, 80 g, random headings) and three pads of the same
colours lie on the table, spread over x 0.38..0.64, |y| <= 0.25 m (base frame), at least 9 cm apart. Each
episode's goal is one (cube, pad) pair drawn from its seed, and only the episode's instruction names it:
nothing in the observation says which cube or which pad (:attr:`Place.instruction`). Success: the named
cube rests on the named pad (centre within 2 cm of the pad's axis, 1 cm of its resting height) and the
gripper is open; the other cubes may lie anywhere.

``pairs`` chooses the goals: ``train`` draws from the seven pairs of :data:`TRAIN_PAIRS`, ``held_out`` from the
two others (:data:`HELD_OUT_PAIRS`: the red cube on the green pad and the green cube on the red pad; every
colour is seen as a cube and as a pad in training, red and green never together), ``all`` from the nine. ``phrasing``
words the instruction with the templates training episodes use (``train``) or with others
(``held_out``: paraphrases no training episode used). Both change only the goal and the words, so a
policy trained on ``pairs=train`` evaluates on ``pairs=held_out``.

Observations (base frame; none depends on the goal): ``obs.object_pos`` [3,3] and ``obs.object_quat``
[3,4] (cubes in colour order), ``obs.pad_pos`` [3,3] (pad centres on the table), and the near-field
features :mod:`demo.sim.stack` found an MLP needs, for every cube: ``obs.object_in_ee`` [3,3] (its
centre in the EE frame, saturated), ``obs.object_yaw4`` [3,2] (sin, cos of 4 x its yaw relative to the
EE's) and ``obs.object_to_pad`` [9,3] (cube i minus pad j's resting place, row ``3 i + j``, saturated).

Expert (state feedback, :mod:`demo.sim.grasp`): holding the named cube, carry it over the others and put
it down on the named pad; holding another, put it back down where it is; holding nothing, grasp the named
cube unless it is in place, then open and rise.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.grasp import BoxState, approach_and_grasp, box_states, carry_and_place, geom_mask, in_hand
from demo.sim.scene import BaseFrame, add_box_body, add_marker_geom, add_mocap_body
from demo.sim.stack import NEAR, StackExpert, StackParams, cube_features
from demo.sim.task import Expert, Task, place_free_body
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env

CUBE_MASS = 0.08  # kg
COLOURS = {"red": (0.85, 0.2, 0.2), "green": (0.2, 0.7, 0.25), "blue": (0.2, 0.35, 0.85)}
REGION = ((0.38, 0.64), (-0.25, 0.25))  # x, y ranges (m, base frame) of the cubes and pads
SPACING = 0.09  # m between any two of them: the open gripper (8 cm) fits between two cubes
GOAL_SLOT = 0  # data.userdata[0:2]: the episode's (cube, pad) colour indices
# (cube, pad) colour indices. Held out: red and green together, in either role. Every colour stays in training
# as a cube and as a pad, and training holds both orders of the other two colour pairs (red-blue, green-blue),
# so the words' roles must be learnt: holding out one order of each pair instead (cube i with pad i + 2) leaves
# every held-out pair the reverse of a training one, which a policy deaf to word order mistakes for it
# (FiLM BC, 2,000 demos: 57/100 on the training pairs, 0/100 on those).
ALL_PAIRS = tuple((c, p) for c in range(3) for p in range(3))
HELD_OUT_PAIRS = ((0, 1), (1, 0))
TRAIN_PAIRS = tuple(pair for pair in ALL_PAIRS if pair not in HELD_OUT_PAIRS)
PAIRS = {"train": TRAIN_PAIRS, "held_out": HELD_OUT_PAIRS, "all": ALL_PAIRS}
PHRASINGS = {
    "train": ("put the {cube} cube on the {pad} pad", "place the {cube} block on the {pad} pad",
              "move the {cube} cube onto the {pad} pad"),
    "held_out": ("set the {cube} block down on the {pad} pad", "bring the {cube} cube over to the {pad} pad"),
}


class PlaceExpert(Expert):
    Params = StackParams  # stack's grasp and carry settings and their style variations: the same moves
    VARIATIONS = StackExpert.VARIATIONS
    p: StackParams

    def act(self, env: "Env") -> np.ndarray:
        task: Place = env.task  # type: ignore[assignment]
        p = self.p
        boxes, pads = task.boxes(env), task.pads(env)
        ee = env.ee_pose()
        ee_pos, ee_quat = ee
        cube, pad = task.pair(env)
        held = next((i for i, b in enumerate(boxes) if in_hand(env, b, ee)[1]), None)

        def top_of_others(skip: int) -> float:
            return max([b.pos[2] + task.half for i, b in enumerate(boxes) if i != skip], default=0.0)

        if held is not None:
            # The named cube goes to the named pad; another goes back down where it is.
            target = pads[pad] if held == cube else boxes[held].pos
            place = np.array([target[0], target[1], task.half])
            return carry_and_place(self, env, boxes[held], place, top_of_others(held), p.clearance, funnel=p.funnel,
                                   ee=ee)
        if task.in_place(boxes[cube], pads[pad]):
            return self.move(env, np.array([ee_pos[0], ee_pos[1], max(ee_pos[2], top_of_others(-1) + 0.08)]), ee_quat,
                             0.0, ee=ee)
        b = boxes[cube]
        approach_z = max(b.pos[2] + p.grasp_depth + p.approach_height, top_of_others(cube) + 0.04)
        others = [o.pos for i, o in enumerate(boxes) if i != cube]
        a = approach_and_grasp(self, env, b, approach_z, p.grasp_depth, p.grasp_yaw, others, funnel=p.funnel, ee=ee)
        if a is None:  # held now but the contact check above just missed it: hold still
            return self.move(env, ee_pos, ee_quat, 1.0, ee=ee)
        return a


class Place(Task):
    name = "place"
    defaults = {"cube_size": 0.04, "pairs": "train", "phrasing": "train"}
    expert_class = PlaceExpert
    wording_options = ("pairs", "phrasing")

    def __init__(self, **options):
        super().__init__(**options)
        self.half = float(self.options["cube_size"]) / 2
        if not 0.015 <= self.half <= 0.025:
            raise DemoError("place", f"cube_size must be within 0.03..0.05 m, got {self.options['cube_size']}")
        for key, choices in (("pairs", PAIRS), ("phrasing", PHRASINGS)):
            if self.options[key] not in choices:
                raise DemoError("place", f"{key} must be one of {', '.join(choices)}, got {self.options[key]!r}")

    @property
    def horizon(self) -> int:
        return 160

    def build(self, spec: mujoco.MjSpec, base: BaseFrame) -> None:
        h = self.half
        for name, colour in COLOURS.items():
            add_box_body(spec, base, f"cube_{name}", [h] * 3, [*colour, 1.0], CUBE_MASS)
        for name, colour in COLOURS.items():
            pad = add_mocap_body(spec, f"pad_{name}")
            add_marker_geom(pad, mujoco.mjtGeom.mjGEOM_BOX, [h + 0.01, h + 0.01, 0.0008], [*colour, 0.6],
                            pos=[0, 0, 0.0008])
        spec.nuserdata = max(spec.nuserdata, GOAL_SLOT + 2)  # the goal lives in the state (demo.sim.task)

    def bind(self, env: "Env") -> None:
        m = env.model
        self.bodies = [m.body(f"cube_{name}").id for name in COLOURS]
        self.joints = [m.joint(f"cube_{name}_joint").id for name in COLOURS]
        self.masks = [geom_mask(m, f"cube_{name}") for name in COLOURS]
        self.mocaps = [int(m.body_mocapid[m.body(f"pad_{name}").id]) for name in COLOURS]

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        spots: list[np.ndarray] = []
        while len(spots) < 6:
            p = np.array([rng.uniform(*REGION[0]), rng.uniform(*REGION[1])])
            if all(np.linalg.norm(p - q) >= SPACING for q in spots):
                spots.append(p)
        for mocap, xy in zip(self.mocaps, spots[:3]):
            env.set_mocap_pose(mocap, np.array([xy[0], xy[1], 0.0]))
        for joint, xy in zip(self.joints, spots[3:]):
            place_free_body(env, joint, np.array([xy[0], xy[1], self.half]), rng.uniform(-math.pi, math.pi))
        pairs = PAIRS[self.options["pairs"]]
        cube, pad = pairs[int(rng.integers(len(pairs)))]
        env.data.userdata[GOAL_SLOT : GOAL_SLOT + 2] = cube, pad
        templates = PHRASINGS[self.options["phrasing"]]
        names = list(COLOURS)
        self.instruction = templates[int(rng.integers(len(templates)))].format(cube=names[cube], pad=names[pad])

    def pair(self, env: "Env") -> tuple[int, int]:
        """The episode's (cube, pad) colour indices, kept in the simulator state (``data.userdata``)."""
        cube, pad = env.data.userdata[GOAL_SLOT : GOAL_SLOT + 2]
        return int(cube), int(pad)

    def goal(self, env: "Env") -> np.ndarray:
        """The named pad's centre on the table (base frame, m), as the other tasks' goal positions are."""
        return self.pads(env)[self.pair(env)[1]]

    def boxes(self, env: "Env") -> list[BoxState]:
        return box_states(env, self.bodies, self.masks, self.half)

    def pads(self, env: "Env") -> list[np.ndarray]:
        """The pads' centres on the table (base frame, m), in colour order."""
        return [env.mocap_pose(mocap)[0] for mocap in self.mocaps]

    def in_place(self, box: BoxState, pad: np.ndarray, xy_tol: float = 0.02, z_tol: float = 0.01) -> bool:
        """The cube rests on the pad."""
        return math.hypot(box.pos[0] - pad[0], box.pos[1] - pad[1]) <= xy_tol and abs(box.pos[2] - self.half) <= z_tol

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        colours = ", ".join(COLOURS)
        return {
            "obs.object_pos": FeatureSpec((3, 3), "float32", f"cube centres ({colours}), base frame", "m", ("x", "y", "z")),
            "obs.object_quat": FeatureSpec((3, 4), "float32", f"cube orientations ({colours}), base frame, w >= 0", "1",
                                           ("w", "x", "y", "z")),
            "obs.pad_pos": FeatureSpec((3, 3), "float32", f"pad centres on the table ({colours}), base frame", "m",
                                       ("x", "y", "z")),
            "obs.object_in_ee": FeatureSpec((3, 3), "float32", f"cube centres in the EE frame, saturated: {NEAR} tanh(p / {NEAR})",
                                            "m", ("x", "y", "z")),
            "obs.object_yaw4": FeatureSpec((3, 2), "float32", "sin, cos of 4 x (cube yaw - EE yaw)", "1", ("sin", "cos")),
            "obs.object_to_pad": FeatureSpec((9, 3), "float32", "cube i minus pad j's resting place (row 3 i + j), base "
                                             f"frame, saturated: {NEAR} tanh(d / {NEAR})", "m", ("x", "y", "z")),
        }

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        pos, quat, in_ee, yaw4 = cube_features(env, self.bodies)
        pads = np.stack(self.pads(env))
        rest = pads + np.array([0.0, 0.0, self.half])  # where a cube rests on each pad
        to_pad = NEAR * np.tanh((pos[:, None, :] - rest[None, :, :]) / NEAR)  # [cube, pad, 3]
        out["obs.object_pos"], out["obs.object_quat"] = pos.astype(np.float32), quat
        out["obs.pad_pos"] = pads.astype(np.float32)
        out["obs.object_in_ee"], out["obs.object_yaw4"] = in_ee, yaw4
        out["obs.object_to_pad"] = to_pad.reshape(9, 3).astype(np.float32)

    def success(self, env: "Env") -> bool:
        cube, pad = self.pair(env)
        return self.in_place(self.boxes(env)[cube], self.pads(env)[pad]) and env.gripper_closedness() < 0.5
