"""The one error type the CLI turns into a one-line message, and the one-line rendering of OS errors."""

from __future__ import annotations

import errno
import re
from pathlib import Path

# Names a command gives to what it is building before renaming it into place (``.out.zarr.tmp-123``,
# ``.x.json.tmp``, ``.out.zarr.old-123``): an error names the file the user asked for instead.
_STAGED = re.compile(r"^\.(?P<name>.+)\.(?:tmp|old)(?:-\d+)?$")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")

# What an OS error means to someone who ran a command: the condition, not the C library's words.
OS_PROBLEMS = {
    errno.ENOSPC: "disk full (no space left on device)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large for this file system or the file-size limit (ulimit -f)",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "no such file or folder",
    errno.EISDIR: "is a folder, not a file",
    errno.ENAMETOOLONG: "file name too long",
    errno.EIO: "input/output error (failing disk or network file system)",
    errno.EMFILE: "too many open files",
    errno.ELOOP: "too many levels of symbolic links",
}


def one_line(text: object) -> str:
    """``text`` as one line: whitespace runs (newlines included) become one space, and other control
    characters (terminal escapes from an untrusted file name or dataset) are shown as ``\\xNN``."""
    flat = " ".join(str(text).split())
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", flat)


def first_line(exc: BaseException, limit: int = 200) -> str:
    """An exception's first line (at most ``limit`` characters; its type's name when it says nothing),
    to quote a library's error inside one of ours."""
    text = str(exc).strip()
    return text.splitlines()[0][:limit] if text else type(exc).__name__


class DemoError(Exception):
    """A problem the user can fix, naming the file (or object) it is about.

    The CLI prints ``error: <where>: <problem>`` on one line and exits non-zero; library callers
    catch it like any exception. ``where`` and ``problem`` are kept as one line each.
    """

    def __init__(self, where: str | Path | None, problem: str, exit_code: int = 1):
        self.where = one_line(where) if where is not None else None
        self.problem = one_line(problem)
        self.exit_code = exit_code
        super().__init__(f"{self.where}: {self.problem}" if self.where else self.problem)

    def __reduce__(self) -> tuple:
        # Errors raised in worker processes travel back by pickle.
        return (DemoError, (self.where, self.problem, self.exit_code))


def user_path(path: str | Path) -> Path:
    """``path`` as the user named it: a staged sibling (``.NAME.tmp-PID/...``) becomes ``NAME``."""
    parts = Path(path).parts
    for i, part in enumerate(parts):
        match = _STAGED.match(part)
        if match:
            return Path(*parts[:i], match.group("name"))
    return Path(path)


def os_error(exc: OSError, fallback: str | Path | None = None) -> DemoError:
    """A :class:`DemoError` for an OS error: the file it names (else ``fallback``, e.g. the command's
    ``--out``), and what went wrong in words (``disk full``, ``read-only file system``, ...)."""
    filename = exc.filename if isinstance(exc.filename, (str, Path)) else None
    where = user_path(filename) if filename else fallback
    code = exc.errno
    if code in (errno.ENOTDIR, errno.EEXIST) and filename:
        blocking = _regular_file_in(Path(filename))
        if blocking is not None:
            return DemoError(user_path(blocking), "is a file, not a folder")
    if code == errno.EEXIST:
        problem = "already exists"
    elif code == errno.ENOTDIR:
        problem = "is not a folder"
    else:
        problem = OS_PROBLEMS.get(code) or (exc.strerror or type(exc).__name__)
    return DemoError(where, problem)


def _regular_file_in(path: Path) -> Path | None:
    """``path`` or its nearest existing ancestor, if that is a file (a folder was needed there)."""
    for candidate in (path, *path.parents):
        if candidate.is_symlink() or candidate.exists():
            return candidate if not candidate.is_dir() else None
    return None
