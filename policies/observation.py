"""The policy's observation: a fixed concatenation of low-dimensional ``obs.*`` keys.

The order of ``keys`` is the order of the concatenation, recorded in the run so that evaluation
builds exactly the vector the policy was trained on. A key of any float shape is flattened in C
order (``obs.object_pos`` ``[K, 3]`` becomes ``3K`` values).

Camera images (``obs.image_*``, uint8 ``[H, W, 3]``) are not part of the vector: they are listed in
``images`` and reach the policy as they are, for its image encoders (:mod:`demo.policies.visuomotor`).
A store with cameras trains by default on its images and the robot's proprioception
(:data:`PROPRIO_PREFIXES`: joint positions, gripper, end-effector pose), never on object poses,
which a real robot has no sensor for; ``--obs-keys`` names the keys to use instead, with the
shorthands ``images`` (every camera), ``proprio`` and ``all`` (every low-dim key).

Quaternions (keys ending in ``_quat`` whose last axis is 4, wxyz) enter as the first two columns
of their rotation matrix ("6D", Zhou et al. 2019), ``[K, 4]`` -> ``6K`` values. A quaternion and
its negative are the same rotation, and the stores keep ``w >= 0``; a gripper pointing down has
``w`` near 0, so its stored quaternion flips sign between nearby orientations: a network would see
a jump where nothing moved. The 6D form is continuous and sign-free.

A key may also be a difference ``"obs.a-obs.b"`` of two position keys whose last axes match
(``obs.object_pos`` ``[K, 3]`` minus ``obs.ee_pos`` ``[3]`` gives every object relative to the
gripper). By default every ``*_pos`` key with 3-vectors gets its offset from ``obs.ee_pos`` added:
a grasp decision hinges on centimetres of that offset, which an MLP would otherwise have to compute
as the difference of two inputs each normalised over half a metre. A difference of two quaternion
keys (``"obs.goal_quat-obs.ee_quat"``) is the first one's orientation in the second one's frame,
``R_b^T R_a``, in the same 6D form: the rotation left to do, whatever the two absolute orientations.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.store import FeatureSpec
from demo.store.episode_store import IMAGE_PREFIX

STATE = "state"  # the low-dim vector's entry in an observation dict (with cameras)
MAX_LOW_DIM = 4096  # values per frame; anything larger is not a state vector
# The robot's own sensors: what a real arm measures without a camera (velocities are left out by default).
# obs.agent_*: the robot's own state in LeRobot's Gymnasium environments (gym-aloha's 14 joint positions, PushT's
# pusher), beside which they may observe an object's pose that a camera policy must not be given.
PROPRIO_PREFIXES = ("obs.joint_", "obs.gripper", "obs.ee_", "obs.agent_")
# The simulator's state of the objects, recorded beside a camera for the experts and for --aux-target (gym-aloha's
# env_state, Meta-World's 39-D state): what a camera policy must not be given, never a default input.
PRIVILEGED_KEYS = ("obs.env_state",)
QUAT_TO_ROT6D = "quat_to_rot6d"
DIFFERENCE = "difference"
RELATIVE_ROTATION = "relative_rotation"
PAIRED = (DIFFERENCE, RELATIVE_ROTATION)  # transforms of a key "obs.a-obs.b"


def is_low_dim(key: str, spec: FeatureSpec) -> bool:
    size = int(np.prod(spec.shape, dtype=np.int64)) if spec.shape else 1
    return (
        key.startswith("obs.")
        and not key.startswith(IMAGE_PREFIX)
        and np.dtype(spec.dtype).kind == "f"
        and size <= MAX_LOW_DIM
    )


def low_dim_keys(features: Mapping[str, FeatureSpec]) -> list[str]:
    """Every low-dimensional float ``obs.*`` key (no images), in store order."""
    return [k for k, spec in features.items() if is_low_dim(k, spec)]


REFERENCE_KEY = "obs.ee_pos"


def is_image(key: str, spec: FeatureSpec) -> bool:
    return key.startswith(IMAGE_PREFIX) and np.dtype(spec.dtype) == np.uint8 and len(spec.shape) == 3 and spec.shape[2] == 3


def image_keys(features: Mapping[str, FeatureSpec]) -> list[str]:
    """Every camera image ``obs.image_*`` (uint8 [H, W, 3]), in store order."""
    return [k for k, spec in features.items() if is_image(k, spec)]


def proprio_keys(features: Mapping[str, FeatureSpec]) -> list[str]:
    """The robot's own low-dim keys (joints, gripper, end-effector), without velocities."""
    return [k for k in low_dim_keys(features) if k.startswith(PROPRIO_PREFIXES) and not k.endswith("_vel")]


def default_keys(features: Mapping[str, FeatureSpec]) -> list[str]:
    """Images + proprioception for a store with cameras (the low-dim keys where none is a robot's own);
    otherwise the state keys below.

    The state keys: the low-dim keys without velocities (``*_vel``), plus positions relative to the end-effector.

    Velocities let a cloned policy read the expert's last action off the state (the arm moves the
    way it was just told to): the "copycat" shortcut of causal confusion (de Haan et al. 2019,
    Wen et al. 2020). It fits the demonstrations and fails in closed loop: on ``pick`` (100 demos,
    MLP) adding ``obs.joint_vel`` took rollout success from 43% to 17%. ``--obs-keys all`` keeps them.
    """
    if image_keys(features):
        # A store of another tool's (a Gymnasium env, a LeRobot dataset) names no joints: its own low-dim
        # state (obs.state) is its proprioception.
        state = [k for k in low_dim_keys(features) if not k.endswith("_vel") and k not in PRIVILEGED_KEYS]
        return image_keys(features) + (proprio_keys(features) or state)
    keys = [k for k in low_dim_keys(features) if not k.endswith("_vel")] or low_dim_keys(features)
    ref = features.get(REFERENCE_KEY)
    if ref is not None and ref.shape == (3,):
        keys += [f"{k}-{REFERENCE_KEY}" for k in list(keys)
                 if k != REFERENCE_KEY and k.endswith("_pos") and features[k].shape[-1:] == (3,)]
    return keys


def _difference(key: str) -> tuple[str, str] | None:
    a, sep, b = key.partition("-")
    return (a, b) if sep else None


def is_quaternion(key: str, spec: FeatureSpec) -> bool:
    return key.endswith("_quat") and len(spec.shape) >= 1 and spec.shape[-1] == 4


def quat_to_rot6d(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` wxyz (any norm, any sign) -> ``[..., 6]``: rotation matrix columns 0 and 1."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-12)
    w, x, y, z = np.moveaxis(q, -1, 0)
    col0 = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)]
    col1 = [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)]
    return np.stack(col0 + col1, axis=-1).astype(np.float32)


def relative_rot6d(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """``[..., 4]`` wxyz ``a`` and ``b`` -> ``[..., 6]``: columns 0 and 1 of ``R_b^T R_a`` (a in b's frame)."""
    a, b = quat_to_rot6d(qa).astype(np.float64), quat_to_rot6d(qb).astype(np.float64)
    b_cols = (b[..., :3], b[..., 3:], np.cross(b[..., :3], b[..., 3:]))
    cols = [np.sum(bc * a[..., i:i + 3], axis=-1) for i in (0, 3) for bc in b_cols]
    return np.stack(cols, axis=-1).astype(np.float32)


def camera_list(images: Iterable[tuple[str, Sequence[int]]]) -> list[tuple[str, int, int]]:
    """``(key obs.image_<name>, shape [H, W, 3])`` pairs -> the cameras an environment renders: (name, width, height)."""
    return [(key[len(IMAGE_PREFIX):], int(shape[1]), int(shape[0])) for key, shape in images]


SHORTHANDS = {"all": low_dim_keys, "images": image_keys, "proprio": proprio_keys}


def expand_keys(features: Mapping[str, FeatureSpec], keys: Sequence[str]) -> list[str]:
    """``keys`` with the shorthands ``all``, ``images``, ``proprio`` replaced by what they name here."""
    out: list[str] = []
    for key in keys:
        for k in SHORTHANDS[key](features) if key in SHORTHANDS else [key]:
            if k not in out:
                out.append(k)
    return out


@dataclass(frozen=True)
class ObsSpec:
    """What a policy observes: low-dim ``keys`` concatenated into one vector, and camera ``images``."""

    keys: tuple[str, ...]
    dims: tuple[int, ...]  # values each key contributes (after its transform)
    transforms: tuple[str, ...] = ()  # per key: "" or QUAT_TO_ROT6D
    images: tuple[str, ...] = ()  # camera keys obs.image_<name>, uint8
    image_shapes: tuple[tuple[int, int, int], ...] = ()  # per camera [H, W, 3]

    def __post_init__(self) -> None:
        if not self.transforms:
            object.__setattr__(self, "transforms", ("",) * len(self.keys))

    @property
    def dim(self) -> int:
        return int(sum(self.dims))

    def cameras(self) -> list[tuple[str, int, int]]:
        """The cameras an environment must render for this policy: (name, width, height)."""
        return camera_list(zip(self.images, self.image_shapes))

    @property
    def source_keys(self) -> list[str]:
        """The store/env keys the vector is built from."""
        out: list[str] = []
        for key, t in zip(self.keys, self.transforms):
            for k in (_difference(key) or (key,)) if t in PAIRED else (key,):
                if k not in out:
                    out.append(k)
        return out

    @classmethod
    def from_features(
        cls, features: Mapping[str, FeatureSpec], keys: Sequence[str] | None = None, where: str = "store"
    ) -> "ObsSpec":
        chosen = default_keys(features) if not keys else expand_keys(features, keys)
        images = [k for k in chosen if k.startswith(IMAGE_PREFIX)]
        chosen = [k for k in chosen if not k.startswith(IMAGE_PREFIX)]
        for key in images:
            if key not in features or not is_image(key, features[key]):
                known = ", ".join(image_keys(features)) or "none"
                raise DemoError(where, f"has no camera image {key!r} (cameras: {known})")
        if not chosen:
            what = "besides its images (add e.g. obs.joint_pos)" if images else "to train on"
            raise DemoError(where, f"has no low-dimensional obs.* features {what}")
        dims, transforms = [], []
        for key in chosen:
            pair = _difference(key)
            if pair is not None:
                a, b = pair
                for k in pair:
                    if k not in features or not is_low_dim(k, features[k]):
                        raise DemoError(where, f"{key}: {k!r} is not a low-dimensional observation of this store")
                if features[a].shape[-1:] != features[b].shape[-1:] or len(features[b].shape) != 1:
                    raise DemoError(where, f"{key}: shapes {features[a].shape} and {features[b].shape} do not subtract")
                rotation = is_quaternion(a, features[a])
                if rotation != is_quaternion(b, features[b]):
                    raise DemoError(where, f"{key}: a quaternion and a vector do not subtract")
                size = int(np.prod(features[a].shape, dtype=np.int64))
                dims.append(size // 4 * 6 if rotation else size)
                transforms.append(RELATIVE_ROTATION if rotation else DIFFERENCE)
                continue
            if key not in features:
                known = ", ".join(low_dim_keys(features)) or "none"
                raise DemoError(where, f"has no observation {key!r} (low-dim obs keys: {known})")
            spec = features[key]
            if not is_low_dim(key, spec):
                raise DemoError(where, f"{key} ({spec.dtype} {spec.shape}) is not a low-dimensional float observation")
            size = int(np.prod(spec.shape, dtype=np.int64)) if spec.shape else 1
            if is_quaternion(key, spec):
                dims.append(size // 4 * 6)
                transforms.append(QUAT_TO_ROT6D)
            else:
                dims.append(size)
                transforms.append("")
        shapes = tuple(tuple(int(x) for x in features[k].shape) for k in images)
        return cls(tuple(chosen), tuple(dims), tuple(transforms), tuple(images), shapes)  # type: ignore[arg-type]

    def layout(self, features: Mapping[str, FeatureSpec]) -> tuple[tuple[int, int], ...]:
        """Per low-dim key, in the vector's order: ``(rows, values per row)``. A key of shape ``(N, k)`` (one row
        per object: three cubes' positions are ``(3, 3)``) holds N rows, any other key one; a difference
        ``obs.a-obs.b`` has ``obs.a``'s rows."""
        out = []
        for key, d, t in zip(self.keys, self.dims, self.transforms):
            shape = features[_difference(key)[0] if t in PAIRED else key].shape  # type: ignore[index]
            rows = int(shape[0]) if len(shape) >= 2 and shape[0] > 0 and d % int(shape[0]) == 0 else 1
            out.append((rows, d // rows))
        return tuple(out)

    def _part(self, data: Mapping[str, np.ndarray], key: str, d: int, transform: str, n: int | None) -> np.ndarray:
        if transform in PAIRED:
            a, b = _difference(key)  # type: ignore[misc]
            av, bv = np.asarray(data[a], dtype=np.float32), np.asarray(data[b], dtype=np.float32)
            if transform == RELATIVE_ROTATION:
                arr = relative_rot6d(av.reshape(-1, 4) if n is None else av.reshape(n, -1, 4),
                                     bv.reshape(1, 4) if n is None else bv.reshape(n, 1, 4))
            elif n is None:
                arr = av.reshape(-1, bv.shape[-1]) - bv.reshape(1, -1)
            else:
                arr = av.reshape(n, -1, bv.shape[-1]) - bv.reshape(n, 1, -1)
            return arr.reshape(d) if n is None else arr.reshape(n, d)
        arr = np.asarray(data[key], dtype=np.float32)
        if transform == QUAT_TO_ROT6D:
            arr = quat_to_rot6d(arr.reshape(-1, 4) if n is None else arr.reshape(n, -1, 4))
        return arr.reshape(d) if n is None else arr.reshape(n, d)

    def concat(self, data: Mapping[str, np.ndarray]) -> np.ndarray:
        """Frames ``{key: [N, ...]}`` -> ``[N, dim]`` float32."""
        first = self.keys[0]
        n = len(data[(_difference(first) or (first,))[0] if self.transforms[0] in PAIRED else first])
        return np.concatenate([self._part(data, k, d, t, n) for k, d, t in zip(self.keys, self.dims, self.transforms)], axis=1)

    def vector(self, frame: Mapping[str, np.ndarray]) -> np.ndarray:
        """One frame ``{key: [...]}`` -> ``[dim]`` float32."""
        return np.concatenate([self._part(frame, k, d, t, None) for k, d, t in zip(self.keys, self.dims, self.transforms)])

    def check_against(self, features: Mapping[str, FeatureSpec], where: str) -> None:
        """Refuse an environment/store whose observations differ from the ones trained on."""
        for key, shape in zip(self.images, self.image_shapes):
            if key not in features:
                raise DemoError(where, f"has no camera image {key!r}, which the policy was trained on")
            if tuple(features[key].shape) != tuple(shape):
                raise DemoError(where, f"camera image {key} is {tuple(features[key].shape)}; the policy was trained on {tuple(shape)}")
        for key, d, t in zip(self.keys, self.dims, self.transforms):
            if t in PAIRED:
                pair = _difference(key) or (key,)  # not "a-b": then it names a missing observation
                missing = [k for k in pair if k not in features]
                if missing:
                    raise DemoError(where, f"has no observation {missing[0]!r}, which the policy was trained on")
                key = pair[0]
            if key not in features:
                raise DemoError(where, f"has no observation {key!r}, which the policy was trained on")
            shape = features[key].shape
            have = int(np.prod(shape, dtype=np.int64)) if shape else 1
            if t in (QUAT_TO_ROT6D, RELATIVE_ROTATION):
                have = have // 4 * 6
            if have != d:
                raise DemoError(where, f"observation {key} has a different size ({shape}) from the one the policy was trained on")

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"keys": list(self.keys), "dims": list(self.dims), "transforms": list(self.transforms)}
        if self.images:  # recorded only when set: state runs read as before
            d["images"] = {k: list(s) for k, s in zip(self.images, self.image_shapes)}
        return d

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> "ObsSpec":
        transforms = tuple(d.get("transforms") or ())
        for t in transforms:
            if t not in ("", QUAT_TO_ROT6D, *PAIRED):
                raise ValueError(f"unknown observation transform {t!r}")
        images = d.get("images") or {}
        shapes = tuple(tuple(int(x) for x in s) for s in images.values())
        if any(len(s) != 3 or s[2] != 3 or not (1 <= s[0] <= 4096 and 1 <= s[1] <= 4096) for s in shapes):
            raise ValueError("camera image shapes must be [H, W, 3]")
        if not all(isinstance(k, str) and k.startswith(IMAGE_PREFIX) for k in images):
            raise ValueError(f"camera image keys must start with {IMAGE_PREFIX}")
        return cls(tuple(d["keys"]), tuple(int(x) for x in d["dims"]), transforms, tuple(images), shapes)
