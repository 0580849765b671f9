"""What a store holds: per-frame features, the action representation, and the root metadata.

Data keys follow one naming scheme so every stage knows what a key is for:

- ``action``: the action label in the store's action representation (see :class:`ActionSpec`).
- ``obs.<name>``: low-dimensional observations or camera images a policy may read.
- ``sim.<name>``: simulator state needed to replay or re-render a frame (``sim.state`` is MuJoCo's
  full integration state, ``mj_getState(..., mjSTATE_INTEGRATION)``).
- ``info.<name>``: anything else recorded per frame (executed action under noise, EE targets, ...).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

FORMAT_NAME = "demo-episodes"
SCHEMA_VERSION = 1
MAX_FPS = 10_000.0  # Hz; a recorded rate beyond it (or NaN, or <= 0) is corrupted metadata


def _object(value: Any, what: str) -> dict[str, Any]:
    """A JSON object read from metadata, else TypeError (readers turn it into one line naming the file)."""
    if not isinstance(value, dict):
        raise TypeError(f"{what} must be a JSON object, got {type(value).__name__}")
    return value


def check_fps(value: Any) -> float:
    """A frame rate read from metadata: a finite number in (0, MAX_FPS] Hz, else ValueError."""
    try:
        fps = float(value)
    except OverflowError:  # an integer too large for a float
        fps = math.inf
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise ValueError(f"fps {value!r} is not a frame rate in (0, {MAX_FPS:g}] Hz")
    return fps


@dataclass(frozen=True)
class FeatureSpec:
    """One per-frame array: its shape *per frame*, dtype, meaning and units."""

    shape: tuple[int, ...]
    dtype: str = "float32"
    description: str = ""
    units: str = ""
    names: tuple[str, ...] | None = None

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["shape"] = list(self.shape)
        d["names"] = list(self.names) if self.names is not None else None
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "FeatureSpec":
        names = _object(d, "feature").get("names")
        return cls(
            shape=tuple(int(s) for s in d["shape"]),
            dtype=str(d.get("dtype", "float32")),
            description=str(d.get("description", "")),
            units=str(d.get("units", "")),
            names=tuple(names) if names is not None else None,
        )

    @property
    def np_dtype(self) -> np.dtype:
        return np.dtype(self.dtype)


IMAGE_CHANNELS = (1, 3, 4)  # gray, RGB, RGBA


def is_image(spec: FeatureSpec) -> bool:
    """Camera images: uint8 ``[H, W, C]`` with 1, 3 or 4 channels."""
    return spec.dtype == "uint8" and len(spec.shape) == 3 and spec.shape[2] in IMAGE_CHANNELS


@dataclass(frozen=True)
class ActionSpec:
    """How the ``action`` array is to be read, so that ``convert`` and ``train`` never guess.

    ``name`` is a representation known to :mod:`demo.convert` (``joint_pos``, ``joint_vel``,
    ``ee_abs``, ``ee_delta``, ``ee7``, ...); ``params`` carries representation options such as the
    rotation form of absolute end-effector targets.
    """

    name: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    frame: str = "base"
    description: str = ""
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.names) != len(self.units):
            raise ValueError(f"action {self.name}: {len(self.names)} names but {len(self.units)} units")

    @property
    def dim(self) -> int:
        return len(self.names)

    def feature(self) -> FeatureSpec:
        return FeatureSpec(
            shape=(self.dim,),
            dtype="float32",
            description=f"action ({self.name}) {self.description}".strip(),
            units=",".join(self.units),
            names=self.names,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "dim": self.dim,
            "names": list(self.names),
            "units": list(self.units),
            "frame": self.frame,
            "description": self.description,
            "params": dict(self.params),
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ActionSpec":
        return cls(
            name=str(_object(d, "action")["name"]),
            names=tuple(d["names"]),
            units=tuple(d["units"]),
            frame=str(d.get("frame", "base")),
            description=str(d.get("description", "")),
            params=dict(d.get("params") or {}),
        )


@dataclass
class StoreMeta:
    """Root metadata of a store (kept in the zarr root group's attributes under ``"demo"``).

    ``robot`` and ``task`` are small JSON dicts (at least ``{"name": ...}``); ``provenance`` is a
    list of records of how the store came to be (collected, converted, curated, imported, ...).
    """

    fps: float
    features: dict[str, FeatureSpec]
    action: ActionSpec
    robot: dict[str, Any] | None = None
    task: dict[str, Any] | None = None
    provenance: list[dict[str, Any]] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)
    format: str = FORMAT_NAME
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        if "action" not in self.features:
            self.features = {"action": self.action.feature(), **self.features}

    @property
    def obs_keys(self) -> list[str]:
        return [k for k in self.features if k.startswith("obs.")]

    def to_json(self) -> dict[str, Any]:
        return {
            "format": self.format,
            "schema_version": self.schema_version,
            "fps": self.fps,
            "robot": self.robot,
            "task": self.task,
            "action": self.action.to_json(),
            "features": {k: v.to_json() for k, v in self.features.items()},
            "provenance": self.provenance,
            "extra": self.extra,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "StoreMeta":
        return cls(
            fps=check_fps(d["fps"]),
            features={k: FeatureSpec.from_json(v) for k, v in _object(d["features"], "features").items()},
            action=ActionSpec.from_json(d["action"]),
            robot=None if d.get("robot") is None else _object(d["robot"], "robot"),
            task=None if d.get("task") is None else _object(d["task"], "task"),
            provenance=list(d.get("provenance") or []),
            extra=dict(d.get("extra") or {}),
            format=str(d.get("format")),
            schema_version=int(d.get("schema_version", -1)),
        )
