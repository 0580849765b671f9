"""Replacing what is at a path without a moment where neither the old nor the new version is there.

A writer that holds the path's lock (:mod:`demo.store.writer_lock`) builds the new version beside
it, in ``.NAME.tmp-PID`` (:func:`staging_path`), then :func:`publish` puts it in place:

- nothing at ``NAME``: ``rename(tmp, NAME)``;
- something at ``NAME``: the two are exchanged atomically (Linux ``renameat2(RENAME_EXCHANGE)``),
  so ``NAME`` is the old or the new version at every instant; then ``tmp``, now the old version,
  is deleted. Where the filesystem cannot exchange: ``NAME`` is renamed to ``.NAME.old-PID``,
  ``tmp`` to ``NAME``, and the old one deleted; a crash between the two renames leaves the old
  version at ``.NAME.old-PID``, which :func:`recover` renames back.

A killed writer leaves its ``.NAME.tmp-*`` (and perhaps ``.NAME.old-*``) behind; the next holder of
the lock calls :func:`recover`, which removes them. Only a holder of the lock may call it: whoever
built them is then certainly gone. Like the store's commits, this protects against crashes and
kills, not power loss (nothing is fsynced).
"""

from __future__ import annotations

import ctypes
import errno
import functools
import os
import shutil
from collections.abc import Callable
from pathlib import Path

_AT_FDCWD = -100
_RENAME_EXCHANGE = 2
_CANNOT_EXCHANGE = {errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP}


def staging_path(path: Path) -> Path:
    """Where a new version of ``path`` is built: a hidden sibling named after this process."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def publish(staged: Path, path: Path) -> None:
    """Put ``staged`` at ``path``, replacing what is there (see the module docstring); ``staged`` is gone after."""
    if not os.path.lexists(path):
        os.rename(staged, path)  # also replaces an empty directory
        return
    if _exchange(staged, path):
        remove(staged)  # now the old version
        return
    old = path.with_name(f".{path.name}.old-{os.getpid()}")
    remove(old)
    os.rename(path, old)
    os.rename(staged, path)
    remove(old)


def recover(path: Path) -> None:
    """After a killed writer of ``path``: restore a version an interrupted swap left aside, remove leftovers.

    Call only while holding ``path``'s writer lock.
    """
    old = interrupted(path)
    if old is not None:
        os.rename(old, path)
    for leftover in _leftovers(path):
        remove(leftover)


def interrupted(path: Path) -> Path | None:
    """The previous version of ``path`` left at ``.NAME.old-PID`` by a swap killed halfway, if ``path`` is gone."""
    if os.path.lexists(path):
        return None
    olds = [p for p in _leftovers(path) if p.name.startswith(f".{path.name}.old-")]
    return max(olds, key=lambda p: p.lstat().st_mtime) if olds else None


def remove(path: Path) -> None:
    """Delete a file, a symlink or a directory tree; nothing to do when it is not there."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif os.path.lexists(path):
        path.unlink()


def _leftovers(path: Path) -> list[Path]:
    prefixes = (f".{path.name}.tmp-", f".{path.name}.old-")
    try:
        siblings = list(path.parent.iterdir())
    except OSError:
        return []
    return [p for p in siblings if p.name.startswith(prefixes) and p.name.rsplit("-", 1)[-1].isdigit()]


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` atomically; False where this OS or filesystem cannot."""
    renameat2 = _renameat2()
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in _CANNOT_EXCHANGE:
        return False
    raise OSError(err, os.strerror(err), str(b))


@functools.cache
def _renameat2() -> Callable[..., int] | None:
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # not Linux, or a libc older than glibc 2.28
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn
