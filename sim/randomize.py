"""Domain randomisation and distribution shifts: the scene's look and physics drawn per episode.

One mechanism serves both. A :class:`Randomization` gives each *kind* a level, 0 (none) to 3; at every
reset (:meth:`demo.sim.env.Env.reset`) the environment restores its nominal model and draws the
episode's values from the episode's reset seed, so any episode replays exactly from its seed, and the
start state is unchanged (the task's own draws use another stream). Each value is a fixed draw
``u`` in [-1, 1] of the seed times the level's amplitude: the same episode at a higher level is shifted
the same way, further, which is what a robustness curve (success against level) needs.

Kinds and their amplitudes at levels 1, 2, 3 (:data:`AMPLITUDES`):

- ``lighting``: every light's diffuse and specular colour, and the headlight's, scaled by ``1 + 0.25,
  0.5, 0.75 u``; each light's direction turned by up to 10, 20, 35 deg about a horizontal axis.
- ``camera``: every camera moved by up to 1, 2, 4 cm per axis, turned by up to 2, 4, 8 deg about a
  random axis, its field of view changed by up to 2, 4, 8 deg.
- ``texture``: the colour of every scene geom (table, floor, the task's objects and markers; not the
  robot's) moved toward a random colour by up to 15, 30, 50% (``u`` in [0, 1]: the nominal colours
  are part of what a randomised training set shows; their materials' colours too).
- ``friction``: the sliding friction of every scene geom scaled by ``1 + 0.3, 0.55, 0.8 u``.
X
- ``noise``: Gaussian pixel noise on every camera image, its standard deviation up to 4, 8, 16 (of 255)
  per episode (``u`` in [0, 1]); each frame's noise is drawn from the seed and the simulation time, so
  a replay from the recorded states sees the same pixels.
- ``blur``: every camera image blurred by a Gaussian of up to 0.5, 1.0, 1.5 px standard deviation per
  episode (``u`` in [0, 1]), as an out-of-focus or moving camera.
- ``latency``: a command takes effect 20, 40, 60 ms after it is given (in 2 ms physics substeps; a
  control step is 50 ms): the previous command acts until then, and the first hold the reset
  configuration. (The experts cope with 50 ms and fail at 100 ms.)

Scene geoms are those of the world body, of free bodies and of mocap bodies: the robot's bodies are
none of these. :data:`PRESETS` are ``light`` (every kind at level 1), ``medium`` (2) and ``heavy`` (3);
a TOML file gives levels per kind (``friction = 2``).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError

KINDS = ("lighting", "camera", "texture", "friction", "mass", "latency", "noise", "blur")
MAX_LEVEL = 3
RANDOMIZE_STREAM = 0xD0A1  # the seed stream of the draws (the task's reset uses the bare seed)
PIXEL_NOISE_STREAM = 0xD0A2  # ... and of each frame's pixel noise (with the simulation time in ms)
# kind -> per level 0..3: the amplitudes of its draws (module docstring)
AMPLITUDES: dict[str, tuple[dict[str, float], ...]] = {
    "lighting": tuple({"scale": s, "turn_deg": t} for s, t in ((0, 0), (0.25, 10), (0.5, 20), (0.75, 35))),
    "camera": tuple({"move_m": p, "turn_deg": t, "fovy_deg": f} for p, t, f in
                    ((0, 0, 0), (0.01, 2, 2), (0.02, 4, 4), (0.04, 8, 8))),
    "texture": tuple({"mix": c} for c in (0, 0.15, 0.3, 0.5)),
    "friction": tuple({"scale": f} for f in (0, 0.3, 0.55, 0.8)),
    "mass": tuple({"log2": m} for m in (0, 0.5, 1, 1.5)),
    "latency": tuple({"ms": k} for k in (0, 20, 40, 60)),
    "noise": tuple({"sigma": n} for n in (0, 4, 8, 16)),
    "blur": tuple({"sigma_px": b} for b in (0, 0.5, 1.0, 1.5)),
}
PRESETS = {"light": 1, "medium": 2, "heavy": 3}


@dataclass(frozen=True)
class Randomization:
    """A level (0..3) per kind; kinds not named are off."""

    levels: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for kind, level in self.levels.items():
            if kind not in KINDS:
                raise DemoError("randomize", f"unknown kind {kind!r} (known: {', '.join(KINDS)})")
            if not isinstance(level, int) or not 0 <= level <= MAX_LEVEL:
                raise DemoError("randomize", f"{kind} level must be an integer 0..{MAX_LEVEL}, got {level!r}")

    @classmethod
    def parse(cls, text: str) -> "Randomization":
        """A preset (``light``, ``medium``, ``heavy``), ``KIND=LEVEL[,KIND=LEVEL...]``, or a TOML file of
        ``kind = level`` lines."""
        if text in PRESETS:
            return cls({kind: PRESETS[text] for kind in KINDS})
        path = Path(text)
        if path.suffix == ".toml" or path.is_file():
            try:
                raw = tomllib.loads(path.read_text())
            except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
                raise DemoError(path, f"not a randomisation TOML ({exc})") from None
            return cls(dict(raw))
        levels: dict[str, int] = {}
        for part in filter(None, text.split(",")):
            kind, eq, level = part.partition("=")
            if not eq or not level.strip().isdigit():
                raise DemoError("--randomize", f"{text!r} is not a preset ({', '.join(PRESETS)}), KIND=LEVEL,... or a "
                                               "TOML file")
            levels[kind.strip()] = int(level)
        return cls(levels)

    def active(self) -> bool:
        return any(self.levels.values())

    def to_json(self) -> dict[str, int]:
        return {k: v for k, v in self.levels.items() if v}


class SceneRandomizer:
    """The nominal values of what randomisation changes in ``model``, and the per-episode draws.

    ``apply(seed)`` restores the nominal model, then draws and writes this episode's values; it returns
    them (JSON-able), by kind."""

    def __init__(self, model: mujoco.MjModel, randomization: Randomization):
        self.model = model
        self.randomization = randomization
        self.nominal = {name: np.array(getattr(model, name)) for name in
                        ("light_diffuse", "light_specular", "light_dir", "cam_pos", "cam_quat", "cam_fovy",
                         "geom_rgba", "mat_rgba", "geom_friction", "body_mass", "body_inertia")}
        self.headlight = (np.array(model.vis.headlight.diffuse), np.array(model.vis.headlight.ambient))
        body = model.geom_bodyid
        free = np.zeros(model.nbody, bool)
        free[model.jnt_bodyid[model.jnt_type == mujoco.mjtJoint.mjJNT_FREE]] = True
        scene_body = free | (model.body_mocapid >= 0)
        scene_body[0] = True  # the world body: table, floor
        self.scene_geoms = np.flatnonzero(scene_body[body])
        self.free_bodies = np.flatnonzero(free)
        self._scratch = mujoco.MjData(model)  # for mj_setConst after masses change

    def restore(self) -> None:
        m = self.model
        changed_mass = not np.array_equal(m.body_mass, self.nominal["body_mass"])
        for name, value in self.nominal.items():
            getattr(m, name)[:] = value
        m.vis.headlight.diffuse[:], m.vis.headlight.ambient[:] = self.headlight
        if changed_mass:
            mujoco.mj_setConst(m, self._scratch)

    def apply(self, seed: int) -> dict[str, Any]:
        self.restore()
        drawn: dict[str, Any] = {}
        for i, kind in enumerate(KINDS):
            level = self.randomization.levels.get(kind, 0)
            if level:
                rng = np.random.default_rng([int(seed), RANDOMIZE_STREAM, i])
                drawn[kind] = getattr(self, f"_{kind}")(rng, AMPLITUDES[kind][level])
        return drawn

    # ------------------------------------------------------------------ one kind each
    def _lighting(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        m = self.model
        scale = 1.0 + a["scale"] * rng.uniform(-1, 1)
        m.light_diffuse[:] = np.clip(self.nominal["light_diffuse"] * scale, 0, 1)
        m.light_specular[:] = np.clip(self.nominal["light_specular"] * scale, 0, 1)
        m.vis.headlight.diffuse[:] = np.clip(self.headlight[0] * scale, 0, 1)
        m.vis.headlight.ambient[:] = np.clip(self.headlight[1] * scale, 0, 1)
        turn = math.radians(a["turn_deg"]) * rng.uniform(-1, 1)
        axis_angle = rng.uniform(0, 2 * math.pi)
        axis = np.array([math.cos(axis_angle), math.sin(axis_angle), 0.0])
        rot = _rotation(axis, turn)
        m.light_dir[:] = self.nominal["light_dir"] @ rot.T
        return {"scale": float(scale), "turn_deg": math.degrees(turn)}

    def _camera(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        m = self.model
        n = m.ncam
        move = a["move_m"] * rng.uniform(-1, 1, (n, 3))
        turns = np.radians(a["turn_deg"]) * rng.uniform(-1, 1, n)
        axes = rng.normal(size=(n, 3))
        fovy = a["fovy_deg"] * rng.uniform(-1, 1, n)
        m.cam_pos[:] = self.nominal["cam_pos"] + move
        for c in range(n):
            q = np.empty(4)
            mujoco.mju_axisAngle2Quat(q, axes[c] / np.linalg.norm(axes[c]), turns[c])
            out = np.empty(4)
            mujoco.mju_mulQuat(out, self.nominal["cam_quat"][c], q)
            m.cam_quat[c] = out
        m.cam_fovy[:] = np.clip(self.nominal["cam_fovy"] + fovy, 10, 120)
        return {"move_m": float(np.abs(move).max(initial=0)), "turn_deg": float(np.degrees(np.abs(turns)).max(initial=0)),
                "fovy_deg": float(np.abs(fovy).max(initial=0))}

    def _texture(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        m = self.model
        mix = a["mix"] * rng.uniform(0.0, 1.0)
        geoms = self.scene_geoms
        colours = rng.uniform(0, 1, (len(geoms), 3))
        m.geom_rgba[geoms, :3] = (1 - mix) * self.nominal["geom_rgba"][geoms, :3] + mix * colours
        mats = m.geom_matid[geoms]
        has = mats >= 0
        m.mat_rgba[mats[has], :3] = (1 - mix) * self.nominal["mat_rgba"][mats[has], :3] + mix * colours[has]
        return {"mix": float(mix)}

    def _friction(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        scale = 1.0 + a["scale"] * rng.uniform(-1, 1)
        self.model.geom_friction[self.scene_geoms, 0] = self.nominal["geom_friction"][self.scene_geoms, 0] * scale
        return {"scale": float(scale)}

    def _mass(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        scale = 2.0 ** (a["log2"] * rng.uniform(-1, 1))
        b = self.free_bodies
        self.model.body_mass[b] = self.nominal["body_mass"][b] * scale
        self.model.body_inertia[b] = self.nominal["body_inertia"][b] * scale
        # The constants derived from masses (inverse weights the contact solver scales by) follow them.
        mujoco.mj_setConst(self.model, self._scratch)
        return {"scale": float(scale)}

    def _latency(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        return {"ms": float(a["ms"])}  # fixed per level: latency is the robot's, not the episode's

    def _noise(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        return {"sigma": float(a["sigma"] * rng.uniform(0.0, 1.0))}  # applied per frame: corrupt_images

    def _blur(self, rng: np.random.Generator, a: dict[str, float]) -> dict[str, Any]:
        return {"sigma_px": float(a["sigma_px"] * rng.uniform(0.0, 1.0))}


def corrupt_images(images: dict[str, np.ndarray], drawn: dict[str, Any], seed: int, time_s: float) -> None:
    """Blur, then add pixel noise to, every ``obs.image_*`` array (uint8 [H, W, 3]) in ``images``, in place,
    as this episode's draws (``drawn``, :meth:`SceneRandomizer.apply`) say. The noise is a function of the
    episode's seed and the simulation time (ms), so the same state at the same time looks the same."""
    blur = drawn.get("blur", {}).get("sigma_px", 0.0)
    sigma = drawn.get("noise", {}).get("sigma", 0.0)
    if blur <= 0 and sigma <= 0:
        return
    rng = np.random.default_rng([int(seed), PIXEL_NOISE_STREAM, int(round(time_s * 1000))])
    for key in sorted(k for k in images if k.startswith("obs.image_")):
        image = images[key].astype(np.float32)
        if blur > 0:
            image = gaussian_blur(image, blur)
        if sigma > 0:
            image += rng.normal(0.0, sigma, image.shape).astype(np.float32)
        images[key] = np.clip(np.rint(image), 0, 255).astype(np.uint8)


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """``image`` [H, W, C] (float) blurred by a separable Gaussian of ``sigma_px`` pixels (edges repeated)."""
    radius = max(1, int(math.ceil(3 * sigma_px)))
    offsets = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 * (offsets / sigma_px) ** 2)
    weights /= weights.sum()
    for axis in (0, 1):
        padded = np.pad(image, [(radius, radius) if a == axis else (0, 0) for a in range(image.ndim)], mode="edge")
        n = image.shape[axis]
        image = sum(w * np.take(padded, np.arange(i, i + n), axis=axis) for i, w in enumerate(weights))
    return image


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` (rad) about the unit ``axis``."""
    q = np.empty(4)
    mujoco.mju_axisAngle2Quat(q, axis, angle)
    mat = np.empty(9)
    mujoco.mju_quat2Mat(mat, q)
    return mat.reshape(3, 3)
