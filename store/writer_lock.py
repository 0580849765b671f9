"""The writer lock of a store's path: one process at a time creates, appends to, replaces or removes it.

The lock is an advisory ``flock`` on a small file *beside* the store, ``.NAME.lock`` in the same
folder, not inside it: it must exist before the store does (two processes creating the same new
store must not both build it) and outlive the directory it guards (a replacement swaps another
directory in at the path). So it locks the path, not a directory: whoever holds it may create,
swap or delete what is at that path, and nobody else may.

The file holds its owner's pid, named in the refusal. It is unlinked on release, while still
locked; a process that opened the old file just before then locks an unlinked file, which
:meth:`WriterLock.acquire` detects (the path no longer leads to the file it locked) and retries.
A crashed owner's lock is released by the kernel; its file stays and is reused.

On object storage (:class:`RemoteWriterLock`) there is no flock: the lock is the object
``.NAME.lock`` beside the store, created only if absent, holding its owner's host and pid, and
deleted on release. On S3 the create is a conditional PUT (``If-None-Match: *``), so of two writers
exactly one gets it; on a backend without conditional writes fsspec checks, then writes, and one
writer per store is then the user's responsibility. Nothing releases the lock of a killed writer:
the next writer on the same machine (host, kernel boot and pid namespace) takes it over when that
pid is gone (a takeover is not atomic: two writers starting at the same moment after a crash could
both proceed); a writer elsewhere is refused, told which object to delete once the owner is gone.
"""

from __future__ import annotations

import fcntl
import os
import socket
from pathlib import Path

from demo.errors import DemoError
from demo.store.location import Remote, StorePath


def acquire(path: StorePath) -> "WriterLock | RemoteWriterLock":
    """The writer lock of the store at ``path``, local or on object storage (see the module docstring)."""
    return RemoteWriterLock.acquire(path) if isinstance(path, Remote) else WriterLock.acquire(path)


def lock_path(path: Path) -> Path:
    """The lock file of the store at ``path`` (symlinks resolved, so every spelling shares one lock)."""
    real = Path(path).resolve()
    return real.with_name(f".{real.name}.lock")


class WriterLock:
    """An exclusive, non-blocking lock on a store path; :meth:`release` it (or let it go with the process)."""

    def __init__(self, path: Path, file: Path, fd: int):
        self.path = path
        self.file = file
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, path: str | Path) -> "WriterLock":
        """Take the lock of ``path`` or raise ``DemoError(path, "is being written by another process (pid N)")``.

        Creates the folder that holds ``path`` if needed (the lock file lives there).
        """
        path = Path(path)
        file = lock_path(path)
        try:
            file.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DemoError(file.parent, f"cannot create the folder for the store ({exc.strerror})") from None
        for _ in range(100):  # each retry means another writer released the lock between our open and flock
            try:
                fd = os.open(file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                raise DemoError(file, f"cannot create the store's lock file ({exc.strerror})") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = _read_pid(fd)
                os.close(fd)
                raise DemoError(path, "is being written by another process" + (f" (pid {owner})" if owner else "")) from None
            if _same_file(fd, file):
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
                return cls(path, file, fd)
            os.close(fd)  # we locked a file its previous owner had just unlinked: start over
        raise DemoError(path, "could not take the writer lock (it changed hands too often)")

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Unlink the lock file (while still holding it), then unlock. Idempotent."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            if _same_file(fd, self.file):
                self.file.unlink()
        except OSError:
            pass  # a read-only or vanished folder: the kernel still drops the lock below
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


def _same_file(fd: int, file: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(file)
    except FileNotFoundError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


class RemoteWriterLock:
    """The writer lock of a store on object storage: the object ``.NAME.lock`` beside it."""

    def __init__(self, path: Remote, file: Remote):
        self.path = path
        self.file = file
        self.held = True

    @classmethod
    def acquire(cls, path: Remote) -> "RemoteWriterLock":
        """Create the lock object, or raise ``DemoError(path, "is being written by another process ...")``."""
        file = path.sibling(f".{path.name}.lock")
        machine = _this_machine()
        took_over = False
        for _ in range(3):
            if file.create(f"{machine} {os.getpid()}\n".encode()):
                return cls(path, file)
            owner_machine, owner_pid = _read_owner(file)
            if owner_pid is None and not file.exists():
                continue  # released in between
            if not took_over and owner_machine == machine and owner_pid is not None and not _alive(owner_pid):
                file.remove()  # its writer was killed on this machine: nothing else releases it
                took_over = True
                continue
            break
        host = (owner_machine or "").split("/")[0]
        owner = f" (pid {owner_pid} on {host})" if owner_pid is not None else ""
        raise DemoError(path, f"is being written by another process{owner}; if that process is gone, "
                              f"delete {file} and retry")

    def release(self) -> None:
        """Delete the lock object. Idempotent."""
        if self.held:
            self.held = False
            try:
                self.file.remove()
            except Exception:
                pass  # unreachable now: the next writer on this machine takes the stale lock over


def _read_owner(file: Remote) -> tuple[str | None, int | None]:
    try:
        host, pid = file.read_bytes().decode("utf-8", "replace").split()
        return host, int(pid)
    except (OSError, ValueError):  # gone in between, or not our format
        return None, None


def _this_machine() -> str:
    """Where a pid means something: the host name, and on Linux the kernel's boot and the pid
    namespace (containers may share a host name, or a kernel, without sharing pids)."""
    parts = [socket.gethostname().replace(" ", "_")]
    try:
        parts.append(Path("/proc/sys/kernel/random/boot_id").read_text().strip())
        parts.append(str(os.stat("/proc/self/ns/pid").st_ino))
    except OSError:
        pass
    return "/".join(parts)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True
