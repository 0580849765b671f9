"""Where a store lives: a local folder (a :class:`~pathlib.Path`) or a prefix on object storage (:class:`Remote`).

A store is named by a path or by a URL that fsspec understands:

- ``pick.zarr``, ``/data/pick.zarr``, ``file:///data/pick.zarr``: a local folder, read and written
  exactly as always (the same code, the same bytes);
- ``s3://bucket/pick.zarr`` (needs s3fs: ``pip install -e '.[s3]'``), ``gs://bucket/pick.zarr``
  (gcsfs: ``'.[gcs]'``), or any other fsspec protocol: objects under that prefix, the same layout.

Credentials and the endpoint come from the backend's own configuration, never from `demo`: for S3,
botocore's environment (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_SESSION_TOKEN``,
``AWS_PROFILE``, ``AWS_DEFAULT_REGION``) and ``AWS_ENDPOINT_URL`` (or ``AWS_ENDPOINT_URL_S3``) for an
S3-compatible server (MinIO, Ceph, a local test server); for GCS, Google's application-default
credentials.

An object store has objects, not files: an object is written whole by one PUT, which is atomic
(a reader gets the old object or the new one, never a mix; S3 and GCS are strongly read-after-write
consistent), and there is no rename, no in-place write and no file lock. :mod:`demo.store.episode_store`
says what that means for a store's commits.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ContextManager

from demo.errors import DemoError

_URL = re.compile(r"^(?P<scheme>[A-Za-z][A-Za-z0-9+.:-]*)://")
# The backends the package's extras install, for the one-line hint when one is missing.
_EXTRAS = {"s3": ("s3fs", "s3"), "s3a": ("s3fs", "s3"), "gs": ("gcsfs", "gcs"), "gcs": ("gcsfs", "gcs")}
# botocore's exception names (matched by name: botocore is optional) for "the endpoint did not answer".
_UNREACHABLE = {"EndpointConnectionError", "ConnectTimeoutError", "ConnectionClosedError", "ReadTimeoutError",
                "ClientConnectorError", "ServerDisconnectedError"}
_NO_CREDENTIALS = {"NoCredentialsError", "PartialCredentialsError", "DefaultCredentialsError"}
# No listings cache: another writer (or zarr's own filesystem instance) may change a prefix at any time.
_OPTIONS: dict[str, Any] = {"use_listings_cache": False}
# s3fs asks an object's size (a HEAD) before each GET to plan a split download of a big object; a
# store's objects are small (~64 KB chunks, a table), so the GET alone does.
_PROTOCOL_OPTIONS: dict[str, dict[str, Any]] = {"s3": {"max_concurrency": 1}, "s3a": {"max_concurrency": 1}}


@dataclass(frozen=True)
class Remote:
    """An object (or a prefix of objects) on object storage: an fsspec filesystem and a key in it.

    ``str()`` gives the URL (``s3://bucket/pick.zarr``), which errors name; ``/`` gives a key below.
    """

    fs: Any  # fsspec.AbstractFileSystem
    key: str  # "bucket/pick.zarr": the filesystem's path, without the protocol or a trailing "/"
    scheme: str  # as the user wrote it: "s3", "gs", ...

    def __str__(self) -> str:
        return f"{self.scheme}://{self.key}"

    def __truediv__(self, part: str) -> "Remote":
        return replace(self, key=f"{self.key}/{part}")

    @property
    def name(self) -> str:
        return self.key.rsplit("/", 1)[-1]

    def sibling(self, name: str) -> "Remote":
        """The key ``name`` beside this one (in the same "folder")."""
        return replace(self, key=f"{self.key.rsplit('/', 1)[0]}/{name}")

    @property
    def bucket(self) -> "Remote":
        return replace(self, key=self.key.split("/", 1)[0])

    def exists(self) -> bool:
        """An object at this key, or any object below it."""
        return bool(self.fs.exists(self.key))

    def is_file(self) -> bool:
        return bool(self.fs.isfile(self.key))

    def read_bytes(self) -> bytes:
        return bytes(self.fs.cat_file(self.key))

    def write_bytes(self, data: bytes) -> None:
        """One PUT: readers see the old object or this one."""
        self.fs.pipe_file(self.key, data)

    def create(self, data: bytes) -> bool:
        """Write the object only if none exists (False when one does).

        On S3 (s3fs) this is a conditional PUT (``If-None-Match: *``), atomic: of two writers, one
        wins. Where the backend has no conditional create, fsspec checks, then writes: not atomic.
        """
        try:
            self.fs.pipe_file(self.key, data, mode="create")
        except FileExistsError:
            return False
        return True

    def remove(self) -> None:
        """Delete the object, or every object below this key; nothing to do when there is none."""
        if self.fs.exists(self.key):
            self.fs.rm(self.key, recursive=True)

    def sizes(self) -> dict[str, int]:
        """Sizes of the objects below this key, by key relative to it (one listing)."""
        found = self.fs.find(self.key, detail=True)
        start = len(self.fs._strip_protocol(self.key).rstrip("/")) + 1
        return {k[start:]: int(info.get("size") or 0) for k, info in found.items()}

    def zarr_store(self, read_only: bool) -> Any:
        """A zarr 3 store over this prefix (``zarr.storage.FsspecStore``, asynchronous)."""
        from zarr.storage import FsspecStore  # deferred: fsspec's store only for a URL

        return FsspecStore.from_url(str(self), storage_options=_options(self.scheme), read_only=read_only)


StorePath = Path | Remote


def store_path(spec: str | Path | Remote) -> StorePath:
    """Where the store named ``spec`` lives: a local Path (also for ``file://``), else a :class:`Remote`.

    Raises a one-line DemoError for an unknown scheme, a backend that is not installed, or a URL
    that names a bucket rather than a store inside one.
    """
    if isinstance(spec, (Path, Remote)):
        return spec
    match = _URL.match(spec)
    if match is None:
        return Path(spec)
    scheme = match.group("scheme")
    protocol = scheme.split("::")[-1]  # fsspec chains ("simplecache::s3://..."): the last one stores
    if protocol in ("file", "local"):
        return Path(spec[len(match.group()):])
    _require_backend(spec, protocol)
    import fsspec  # deferred: fsspec only for a URL

    try:
        fs, key = fsspec.core.url_to_fs(spec, **_options(protocol))
    except Exception as exc:  # the backend's own refusal of its options or of the URL
        raise DemoError(spec, f"cannot use this URL ({_first_line(exc)})") from None
    key = str(key).rstrip("/")
    if "/" not in key:
        raise DemoError(spec, f"names a bucket, not a store in it (e.g. {protocol}://{key or 'bucket'}/pick.zarr)")
    return Remote(fs, key, protocol)


def is_remote(spec: object) -> bool:
    """Whether ``spec`` (a string, Path or Remote) names a store on object storage, without opening anything."""
    if isinstance(spec, Remote):
        return True
    match = _URL.match(spec) if isinstance(spec, str) else None
    return match is not None and match.group("scheme").split("::")[-1] not in ("file", "local")


def absolute(spec: str | Path) -> str:
    """What a record names a store by: a local path made absolute (symlinks resolved), a URL as it is."""
    return str(spec) if is_remote(spec) else str(Path(spec).resolve())


def same_store(a: StorePath, b: StorePath) -> bool:
    """Whether two locations name the same store (local paths after resolving symlinks)."""
    if isinstance(a, Path) and isinstance(b, Path):
        return a.resolve() == b.resolve()
    return str(a).rstrip("/") == str(b).rstrip("/")


def zarr_store(where: StorePath, read_only: bool) -> Any:
    """What ``zarr.open_group`` takes for ``where``: the local folder's name, or an FsspecStore."""
    return where.zarr_store(read_only) if isinstance(where, Remote) else str(where)


def remote_errors(where: StorePath) -> ContextManager[None]:
    """Turn an object store's failures (no such bucket, no endpoint, no credentials, access denied)
    into a one-line DemoError naming ``where``; nothing to do for a local path."""
    return _remote_errors(where) if isinstance(where, Remote) else nullcontext()


@contextmanager
def _remote_errors(where: Remote) -> Iterator[None]:
    try:
        yield
    except DemoError:
        raise
    except Exception as exc:
        problem = remote_problem(exc, where)
        if problem is None:
            raise
        raise DemoError(where, problem) from None


def remote_problem(exc: BaseException, where: Remote) -> str | None:
    """What went wrong talking to the object store, in words; None for an error of another kind."""
    names = {cls.__name__ for cls in type(exc).__mro__}
    text = _first_line(exc)
    if names & _UNREACHABLE:
        return f"cannot reach the object store ({text}); check AWS_ENDPOINT_URL (or the backend's endpoint) and the network"
    if names & _NO_CREDENTIALS:
        return f"no credentials for the object store ({text}); set AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY or AWS_PROFILE"
    if isinstance(exc, FileNotFoundError) and ("bucket does not exist" in text.lower() or "NoSuchBucket" in text):
        return f"bucket {where.bucket} does not exist"
    if isinstance(exc, PermissionError):
        return f"access denied by the object store ({text})"
    return None


def _options(protocol: str) -> dict[str, Any]:
    return {**_OPTIONS, **_PROTOCOL_OPTIONS.get(protocol, {})}


def _require_backend(spec: str, protocol: str) -> None:
    import fsspec  # deferred: fsspec only for a URL

    try:
        fsspec.get_filesystem_class(protocol)
    except ImportError:
        package, extra = _EXTRAS.get(protocol, (None, None))
        if package:
            raise DemoError(spec, f"{protocol}:// needs {package}: pip install -e '.[{extra}]'") from None
        raise DemoError(spec, f"{protocol}:// needs an fsspec backend that is not installed") from None
    except ValueError:
        raise DemoError(spec, f"unknown scheme {protocol}:// (a store is a local path or a URL such as "
                              "s3://bucket/pick.zarr, gs://bucket/pick.zarr, file:///data/pick.zarr)") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:200]
