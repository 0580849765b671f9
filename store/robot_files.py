"""The robot's files kept beside a store's (or a run's) data, so that a copied folder still has its robot.

A non-built-in robot is recorded by content in ``meta.robot`` (see :mod:`demo.sim.robot_record`)::

    {"name": "my_arm",
     "config": "/abs/my_arm.toml",        # the TOML it was read from: informative only
     "toml": {... the config's keys ...},  # "mjcf" relative to the files' folder
     "files": {"my_arm.xml": "<sha256>", "meshes/base.stl": "<sha256>"},
     "source": "/abs"}                     # the folder the files were read from: a fallback

and its files are copied, byte for byte and in the same relative layout, to ``<dir>/robot/``.
This module only moves and checks those files; it knows nothing of MuJoCo.

The record is untrusted data (a store may come from anywhere): every listed name must be a plain
relative POSIX path (no ``..``, no absolute path, no backslash), every hash 64 hex digits, and a
file in a store's ``robot/`` folder must resolve inside it (no symlink out of the store).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
from pathlib import Path, PurePosixPath
from typing import Any

from demo.errors import DemoError
from demo.store.location import is_remote

ROBOT_DIR = "robot"
_STAGING = ".robot.tmp"
_SHA256 = re.compile(r"[0-9a-f]{64}")
MAX_FILES = 10_000


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def safe_name(name: Any, where: object) -> str:
    """``name`` if it is a plain relative POSIX path that stays inside its folder; else DemoError."""
    if not isinstance(name, str) or not name or "\\" in name or "\x00" in name:
        raise DemoError(where, f"robot file name {name!r} is not a relative path")
    path = PurePosixPath(name)
    if path.is_absolute() or str(path) != name or any(part in ("..", ".") for part in path.parts):
        raise DemoError(where, f"robot file name {name!r} must be relative and stay inside the robot folder")
    return name


def file_table(record: dict[str, Any] | None, where: object) -> dict[str, str]:
    """The record's ``files`` ({relative name: sha256}), validated; ``{}`` when it lists none."""
    files = (record or {}).get("files")
    if files is None:
        return {}
    if not isinstance(files, dict) or len(files) > MAX_FILES:
        raise DemoError(where, "robot record 'files' must map file names to sha256 hashes")
    for name, digest in files.items():
        safe_name(name, where)
        if not isinstance(digest, str) or not _SHA256.fullmatch(digest):
            raise DemoError(where, f"robot file {name!r} has no valid sha256 hash in the record")
    return dict(files)


def first_problem(files: dict[str, str], folder: Path, contained: bool) -> tuple[Path, str] | None:
    """``(file, what is wrong)`` for the first listed file that is missing or differs, else None.

    ``contained``: also refuse a file that resolves outside ``folder`` (a store's own copy).
    """
    root = folder.resolve() if contained else folder
    for name, digest in sorted(files.items()):
        path = folder / name
        if contained and not path.resolve().is_relative_to(root):
            return path, "robot file leads outside its folder (symlink), refusing to read it"
        if not path.is_file():
            return path, "robot file missing"
        if sha256_file(path) != digest:
            return path, "robot file differs from the recorded one (sha256 mismatch)"
    return None


def locate(record: dict[str, Any] | None, where: object) -> tuple[Path | None, tuple[str | Path, str] | None]:
    """The folder holding every file the record lists, intact: ``where/robot`` first (a local store
    or run; a store on object storage holds none), then ``source``.

    Returns ``(folder, None)``, or ``(None, problem)`` with the problem found in ``where``'s copy
    (else in the source folder). ``where`` is the store or run directory the record belongs to.
    """
    files = file_table(record, where)
    problem = None
    if is_remote(where):  # MuJoCo reads files: a store on object storage keeps no robot files (copy_robot_files)
        problem = (f"{where}/{ROBOT_DIR}", "robot files of a store on object storage are not read")
    elif where is not None:
        problem = first_problem(files, Path(where) / ROBOT_DIR, contained=True)
        if problem is None:
            return Path(where) / ROBOT_DIR, None
    source = (record or {}).get("source")
    if isinstance(source, str) and Path(source).is_absolute():
        source_problem = first_problem(files, Path(source), contained=False)
        if source_problem is None:
            return Path(source), None
        problem = problem or source_problem
    return None, problem or (Path(str(where or "robot")), "robot record names no folder holding its files")


def copy_robot_files(record: dict[str, Any] | None, origin: object, dest: object) -> bool:
    """Copy the files ``record`` lists (found by :func:`locate` from ``origin``) to ``dest/robot``.

    Staged in ``dest/.robot.tmp`` and renamed into place, so ``dest/robot`` is always either absent,
    the old copy or the complete new one. Returns False (and copies nothing) when the record lists
    no files or none of its folders holds them intact; a reader then reports the missing file.
    ``dest`` on object storage (a :class:`~demo.store.location.Remote`) is refused for a robot with
    files: MuJoCo reads local files, and fetching them back is not implemented.
    """
    files = file_table(record, dest)
    if not files:
        return False
    if is_remote(dest):
        raise DemoError(dest, f"a store on object storage cannot hold a robot's files yet (robot {(record or {}).get('name')!r} "
                              "is not the built-in arm): write it to a local folder")
    folder, _ = locate(record, origin)
    dest = Path(dest)
    target = dest / ROBOT_DIR
    if folder is None:
        return False
    if folder.resolve() == target.resolve() or first_problem(files, target, contained=True) is None:
        return True  # already there (a resumed run, a store copied onto itself)
    staging = dest / _STAGING
    shutil.rmtree(staging, ignore_errors=True)
    for name, digest in files.items():
        out = staging / name
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(folder / name, out)
        if sha256_file(out) != digest:  # changed between the check and the copy
            shutil.rmtree(staging, ignore_errors=True)
            raise DemoError(folder / name, "robot file changed while it was being copied")
    if target.exists():  # a damaged copy: readers already fall back to the source folder
        shutil.rmtree(target)
    os.replace(staging, target)
    return True


def same_body(a: dict[str, Any] | None, b: dict[str, Any] | None) -> bool:
    """Whether two records describe the same arm whatever they are called: the same config keys (the name
    aside) and the same files, by content; the built-in arm by its config."""
    a, b = a or {}, b or {}
    if "files" in a and "files" in b:
        keys = [{k: v for k, v in (r.get("toml") or {}).items() if k != "name"} for r in (a, b)]
        return keys[0] == keys[1] and a.get("files") == b.get("files")
    return "files" not in a and "files" not in b and a.get("config") == b.get("config")


def same_robot(a: dict[str, Any] | None, b: dict[str, Any] | None) -> bool:
    """Whether two records describe the same robot (by content; where it was read from does not count)."""
    a, b = a or {}, b or {}
    if "files" in a and "files" in b:
        return all(a.get(k) == b.get(k) for k in ("name", "toml", "files"))
    return a.get("name") == b.get("name") and a.get("config") == b.get("config")
