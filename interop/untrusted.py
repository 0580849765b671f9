"""Reading another stack's dataset as untrusted input: paths stay inside it, sizes are bounded.

A dataset folder or file may come from anywhere. Importing one must never read a file outside it
(a ``..`` or an absolute path in its metadata, a symlink out of the folder), never say whether a
file outside it exists (a path outside is refused with the same words whether or not its target
is there), and never allocate memory because a number in its metadata says so: every size is
checked against the bounds here, or against the bytes the dataset actually holds, first.
"""

from __future__ import annotations

import math
import re
import string
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.store import spec as store_spec

# Bounds on what metadata may declare (fps: demo.store.spec.MAX_FPS). Real robot-learning data is
# orders of magnitude inside them; beyond them is a corrupted or hostile file, refused before
# anything is allocated.
MAX_FRAME_VALUES = 2**26  # values in one frame of one feature (a 4096 x 4096 RGBA image is 2**26)
MAX_DIM = 2**31 - 1  # one axis of a feature's shape
MAX_EPISODE_FRAMES = 2**31 - 1
MAX_KEY_LENGTH = 100  # characters of a store key (it names a folder of the store)
NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats: what a store's arrays hold
KEY = re.compile(rf"(action|(obs|sim|info)\.[A-Za-z0-9_][A-Za-z0-9_.\-]{{0,{MAX_KEY_LENGTH}}})")

_OUTSIDE = "leads outside the dataset folder; refusing to read it"


def contained(root: Path, relative: str | Path, where: str | Path, what: str) -> Path:
    """``root / relative`` if it stays inside ``root``, else a DemoError on ``where``.

    ``relative`` is a path the dataset names (``what``: e.g. ``data_path``): it must be relative,
    without ``..``, and resolve inside ``root`` through any symlinks. The error is the same whether
    or not the target exists, so a dataset cannot probe the machine it is imported on.
    """
    name = str(relative)
    pure = PurePosixPath(name)
    if not name or "\x00" in name or "\\" in name or pure.is_absolute() or ".." in pure.parts:
        raise DemoError(where, f"{what} {name!r} {_OUTSIDE}")
    return inside(root, root / name, where, what)


def inside(root: Path, path: Path, where: str | Path | None = None, what: str = "file") -> Path:
    """``path`` (under ``root``) if it resolves inside ``root`` through any symlinks, else DemoError."""
    try:
        resolved = path.resolve()
    except (OSError, RuntimeError):  # a symlink loop
        resolved = None
    if resolved is None or not resolved.is_relative_to(root.resolve()):
        raise DemoError(where or path, f"{what} {_OUTSIDE}" if where else _OUTSIDE)
    return path


def check_template(template: Any, where: str | Path, key: str, fields: tuple[str, ...]) -> str:
    """A path template from the dataset's metadata (``data/chunk-{chunk_index:03d}/...``), checked.

    Only the named ``fields`` may appear, each plain or with an integer format (``:03d``): a
    template is data, and ``str.format`` would otherwise reach attributes or build huge strings.
    """
    if not isinstance(template, str):
        raise DemoError(where, f"{key} must be a path template string, got {type(template).__name__}")
    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise DemoError(where, f"{key} {template!r} is not a path template ({exc})") from None
    for _, field, form, conversion in parts:
        if field is None:
            continue
        if field not in fields or conversion or not re.fullmatch(r"(0?[1-9]?d)?", form or ""):
            raise DemoError(where, f"{key} {template!r}: only {{{'}, {'.join(fields)}}} with a format like :03d may appear")
    pure = PurePosixPath(template)
    if pure.is_absolute() or ".." in pure.parts or "\\" in template or "\x00" in template:
        raise DemoError(where, f"{key} {template!r} {_OUTSIDE}")
    return template


def store_key(prefix: str, name: str, taken: set[str], where: str | Path) -> str:
    """A store key ``prefix.<name>`` for a foreign feature name: characters a store key cannot hold
    become ``_`` (a key names a folder), a clash with a key already ``taken`` gets ``_2``, ``_3``..."""
    clean = re.sub(r"[^A-Za-z0-9_\-]", "_", name)[:MAX_KEY_LENGTH] or "_"
    if clean[0] in "-.":
        clean = "_" + clean[1:]
    key, n = f"{prefix}.{clean}", 1
    while key in taken:
        n += 1
        key = f"{prefix}.{clean}_{n}"
    if not KEY.fullmatch(key):
        raise DemoError(where, f"feature {name!r} cannot be named as a store key")
    taken.add(key)
    return key


def check_fps(value: Any, where: str | Path) -> float:
    """A frame rate from metadata (:func:`demo.store.spec.check_fps`), or a DemoError on ``where``."""
    try:
        return store_spec.check_fps(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise DemoError(where, str(exc) if isinstance(exc, ValueError) else f"fps {value!r} is not a number") from None


def check_count(value: Any, where: str | Path, what: str, limit: int = MAX_EPISODE_FRAMES) -> int:
    """A count from metadata (frames, episodes, an index): an integer in [0, limit]."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        if not (isinstance(value, (float, np.floating)) and float(value).is_integer()):
            raise DemoError(where, f"{what} must be an integer, got {value!r}")
    if not 0 <= value <= limit:
        raise DemoError(where, f"{what} {value!r} is not within 0..{limit}")
    return int(value)


def check_feature(key: str, shape: Any, dtype: Any, where: str | Path) -> tuple[tuple[int, ...], str]:
    """A feature's declared per-frame shape and dtype: a valid key, numeric, of bounded size."""
    if not isinstance(key, str) or not KEY.fullmatch(key):
        raise DemoError(where, f"feature key {key!r} is not a store key (action, obs.NAME, sim.NAME or info.NAME)")
    if not isinstance(shape, (list, tuple)) or len(shape) > 8:
        raise DemoError(where, f"{key}: shape {shape!r} is not a list of at most 8 sizes")
    dims = tuple(check_count(d, where, f"{key}: shape size", MAX_DIM) for d in shape)
    if math.prod(dims) > MAX_FRAME_VALUES:
        raise DemoError(where, f"{key}: shape {list(dims)} holds more than {MAX_FRAME_VALUES} values a frame")
    try:
        np_dtype = np.dtype(dtype)
    except (TypeError, ValueError):
        raise DemoError(where, f"{key}: dtype {dtype!r} is not a numeric type") from None
    if np_dtype.kind not in NUMERIC_KINDS or np_dtype.shape or np_dtype.names:
        raise DemoError(where, f"{key}: dtype {dtype!r} is not a numeric type")
    return dims, np_dtype.name  # the native type of that name: a store holds native byte order


def check_meta(meta: Any, where: str | Path) -> None:
    """A StoreMeta read from the dataset (its own record of a demo store): keys, fps and features."""
    check_fps(meta.fps, where)
    for key, feature in meta.features.items():
        check_feature(key, feature.shape, feature.dtype, where)


# The fixed per-episode columns of a store and the Python types their values must have.
INFO_TYPES: dict[str, type] = {"success": bool, "seed": int, "source": str, "operator": str, "task": str}


def check_info(info: dict[str, Any], where: str | Path) -> dict[str, Any]:
    """An episode's fixed columns read from the dataset: each of its type (seed a 64-bit integer)."""
    for key, kind in INFO_TYPES.items():
        value = info.get(key)
        if value is not None and (not isinstance(value, kind) or (kind is int and isinstance(value, bool))):
            raise DemoError(where, f"episode {key} is {value!r}, not a {kind.__name__}")
    if info.get("seed") is not None and not -(2**63) <= info["seed"] < 2**63:
        raise DemoError(where, f"episode seed {info['seed']} is not a 64-bit integer")
    return info
