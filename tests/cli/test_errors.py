"""Every failure is ``error: <file>: <problem>`` on one line at any terminal width, with a non-zero exit:
usage mistakes, OS errors (disk full, read-only, permissions, an --out that is a file), a robot
config pointing at a broken MJCF, a feature name a store cannot hold."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import typer

from demo.cli.main import app
from demo.cli.options import json_option
from demo.errors import DemoError
from demo.interop.sample import make_sample_store
from demo.sim.robot import ASSETS

# Hidden commands raising the OS errors a real write meets, as the OS raises them (errno, file name).
_OS_ERRORS = {
    "enospc": lambda out: OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)),  # a write(): no file name
    "erofs": lambda out: OSError(errno.EROFS, os.strerror(errno.EROFS), str(out.with_name(f".{out.name}.tmp-4242") / "data")),
    "eacces": lambda out: PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(out)),
}


@app.command("raise-os-error", hidden=True)
def _raise_os_error(kind: str, out: Path = typer.Option(..., "--out"), json_out: str = json_option()) -> None:
    raise _OS_ERRORS[kind](out)


@pytest.mark.parametrize("kind,expected", [
    ("enospc", "disk full (no space left on device)"),
    ("erofs", "read-only file system"),
    ("eacces", "permission denied"),
])
def test_os_errors_name_the_file(kind: str, expected: str, tmp_path: Path, one_line_error) -> None:
    out = tmp_path / "x.zarr"
    # Before: `error: OSError: [Errno 28] No space left on device` named no file.
    assert one_line_error(["raise-os-error", kind, "--out", str(out)], rc=1) == f"error: {out}: {expected}"


def test_out_that_is_a_regular_file(tmp_path: Path, one_line_error) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me")
    for out in (notes / "pick.zarr", notes):
        line = one_line_error(["collect", "--task", "reach", "--episodes", "1", "--out", str(out)], rc=1)
        assert line.startswith(f"error: {notes}: "), line
    assert notes.read_text() == "keep me"
    from demo.errors import os_error

    assert os_error(FileExistsError(errno.EEXIST, "File exists", str(notes / "a" / "b"))).where == str(notes)


def test_error_text_is_one_line_and_shows_no_terminal_escapes() -> None:
    from demo.errors import one_line, user_path

    err = DemoError("data/\x1b[2Jx.zarr", "bad\nthing:\n  details")
    assert str(err) == "data/\\x1b[2Jx.zarr: bad thing: details" and "\n" not in str(err)
    assert one_line("a\r\n\tb") == "a b"
    assert user_path("/d/.out.zarr.tmp-123/data/c/0") == Path("/d/out.zarr") and user_path("/d/x.json") == Path("/d/x.json")


def broken_robot(folder: Path) -> Path:
    folder.mkdir()
    shutil.copy(ASSETS / "panda.toml", folder / "robot.toml")
    (folder / "panda.xml").write_text("<mujoco><worldbody><body><geom type='sphere'/></body></worldbody>")  # unclosed
    return folder / "robot.toml"


# Run in a child per terminal width: rich reads COLUMNS when its console is made.
WIDTH_SCRIPT = textwrap.dedent("""
    import contextlib, io, json, sys
    import typer
    from demo.cli.main import app, main

    @app.command("explode", hidden=True)
    def explode() -> None:
        raise ValueError("kaput\\nsecond line of a library's message")

    results = []
    for argv in json.loads(sys.argv[1]):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main(argv)
        results.append([rc, err.getvalue()])
    print(json.dumps(results))
""")


@pytest.mark.slow
@pytest.mark.parametrize("columns", [40, 200])
def test_one_line_at_any_terminal_width(columns: int, tmp_path: Path) -> None:
    store = make_sample_store(tmp_path / "s.zarr", episodes=2)
    toml = broken_robot(tmp_path / "robot")
    notes = tmp_path / "notes.txt"
    notes.write_text("x")
    cases = [
        (["export", str(store), "--format", "csv", "--out", str(tmp_path / "o")],  # before: a 3-line usage box
         2, "error: --format: 'csv' is not one of lerobot, robomimic"),
        (["collect", "--task", "reach", "--episodes", "1", "--robot", str(toml), "--out", str(tmp_path / "r.zarr")],
         1, f"error: {tmp_path / 'robot/panda.xml'}: MJCF does not load: XML parse error 15: "  # before: 2 lines
            f"Error=XML_ERROR_PARSING ErrorID=15 (0xf) Line number=1 (named by {toml.resolve()})"),
        (["train", str(store), "--out", str(tmp_path / "run"), "--frobnicate"],
         2, "error: --frobnicate: no such option of demo train; did you mean --obs-noise or --robot? (see demo train --help)"),
        (["info"], 2, "error: STORE: missing argument (see demo info --help)"),
        (["collect", "--episodes", "many", "--out", str(tmp_path / "c.zarr")],
         2, "error: --episodes: input should be a valid integer, unable to parse string as an integer"),
        (["explode"], 1, "error: ValueError: kaput second line of a library's message (run with --debug for the traceback)"),
    ]
    env = {**os.environ, "COLUMNS": str(columns), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    child = subprocess.run([sys.executable, "-c", WIDTH_SCRIPT, json.dumps([argv for argv, _, _ in cases])],
                           capture_output=True, text=True, timeout=300, env=env)
    assert child.returncode == 0, child.stderr
    for (argv, code, line), (rc, err) in zip(cases, json.loads(child.stdout)):
        assert (rc, err) == (code, line + "\n"), argv


@pytest.mark.slow
def test_a_real_write_failure_names_the_output(tmp_path: Path) -> None:
    """A real write past the file-size limit fails with no file name in the OSError: the line names --out."""
    store = make_sample_store(tmp_path / "s.zarr", episodes=3)
    out = tmp_path / "x.hdf5"
    script = textwrap.dedent(f"""
        import resource, signal, sys
        from demo.cli.main import main
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit then fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
        sys.exit(main(["export", {str(store)!r}, "--format", "robomimic", "--out", {str(out)!r}]))
    """)
    child = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert child.returncode == 1
    assert child.stderr == f"error: {out}: file too large for this file system or the file-size limit (ulimit -f)\n"
    assert not out.exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".x.hdf5.tmp")] == []


def _mount_tmpfs(folder: Path, size_kb: int) -> bool:
    folder.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(folder)], capture_output=True)
    return done.returncode == 0


def test_disk_full_for_real(tmp_path: Path, one_line_error) -> None:
    """A full file system (a small tmpfs): before, the robomimic export crashed (libhdf5 segfaults when
    it cannot flush on close) and other commands named no file."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, 256):
        pytest.skip("needs root and a mountable tmpfs for a real full disk")
    try:
        store = make_sample_store(tmp_path / "s.zarr", episodes=4)
        (disk / "filler").write_bytes(b"\0" * 200_000)
        out = disk / "x.hdf5"
        assert one_line_error(["export", str(store), "--format", "robomimic", "--out", str(out)], rc=1) == \
            f"error: {out}: disk full (no space left on device)"
        assert sorted(p.name for p in disk.iterdir() if not p.name.endswith(".lock")) == ["filler"]
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)
