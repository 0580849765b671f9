"""JSON of results and run files: a plain-JSON copy of Python/numpy values, and atomic file writes
(:func:`replace_atomically`, also what the store rewrites its episode table and chunks with).

Library code (checkpoints, reports) writes its JSON here; :mod:`demo.cli.output` adds only the
CLI's ``--json -`` (stdout) on top, so no library module needs ``demo.cli``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def to_jsonable(obj: Any) -> Any:
    """Plain-JSON copy of ``obj`` (numpy scalars and arrays, paths, NaN as null)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def dumps(obj: Any) -> str:
    """``obj`` as indented JSON (see :func:`to_jsonable`), without a trailing newline."""
    return json.dumps(to_jsonable(obj), indent=2)


def replace_atomically(path: str | Path, write: Callable[[Path], object]) -> None:
    """Create or replace ``path`` by ``write(tmp)`` to a hidden sibling ``.NAME.PID.tmp`` renamed over it.

    Readers see the old file or the new one, never a half-written one. A failed write removes its
    temporary file (a full disk gets its space back; the old file stays); a kill leaves at most the
    ``.tmp`` file behind. The parent folder is created if needed. No fsync: the guarantee is against
    process crashes and kills, not power loss.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as JSON (:func:`dumps`, newline-terminated) to ``path``, atomically.

    A ``path`` that exists and is not a regular file (``/dev/stderr``, a FIFO, a device) is written
    to as it is: replacing it by rename would put a regular file in its place.
    """
    text = dumps(obj) + "\n"
    path = Path(path)
    if path.exists() and not path.is_file():
        with open(path, "w") as stream:
            stream.write(text)
        return
    replace_atomically(path, lambda tmp: tmp.write_text(text))
