"""The fuzz suite's corruptions: every kind of file `demo` reads, broken in seeded ways.

One file of ~720 lines on purpose: it is the catalogue, a section per kind of input, read as a table.

A *source* is a pristine input of one kind (a store, a robot TOML, a VR pose file, a kinesthetic
CSV, a run directory, a LeRobot folder, a robomimic HDF5 file) with the commands that read it. A
*corruption* changes a copy of it: bytes (truncation, bit flips, garbage, an empty file), values
(wrong types, NaN, huge sizes, negative counts) or paths (``..``, absolute paths, symlinks out of
the dataset, HDF5 links and external storage). :func:`cases` lays them out: case ``i`` is
corruption ``i`` mod the number of (source, corruption) pairs, so every corruption runs once in
the first pairs-many cases, with its own seed for what it picks. :func:`run_case` runs the command
in-process and returns what the invariant is checked on.

A corruption either must make the command fail (``expect="fail"``) or may leave a valid input
(``expect="any"``, with the reason): a bit flipped in a number is a different number, a truncated
CSV can end at a line boundary. Either way the command must not crash, must print one line on
failure and must not change the source.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import shutil
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

FAIL = "fail"
ANY = "any"
OUTSIDE = "outside.bin"  # a file beside every case's source: a path trick points at it (or at what is not there)

# ---------------------------------------------------------------------------------------------- sources
Command = Callable[[Path, Path], list[str]]  # (source, scratch folder) -> argv of `demo`


@dataclass(frozen=True)
class Corruption:
    name: str
    apply: Callable[[Path, random.Random], str]  # changes the copy at the path; returns what it did
    expect: str = FAIL
    why: str = ""  # for ANY: why a valid input may remain
    command: str | None = None  # only with this command of the source (default: any of them)


@dataclass(frozen=True)
class Source:
    name: str
    commands: dict[str, Command]
    corruptions: tuple[Corruption, ...]


@dataclass(frozen=True)
class Case:
    index: int
    source: Source
    corruption: Corruption
    command: str
    seed: int

    @property
    def id(self) -> str:
        return f"{self.index}-{self.source.name}-{self.corruption.name}-{self.command.replace(' ', '_')}"


# ---------------------------------------------------------------------------------------------- byte corruptions
def _files(root: Path, pattern: str | tuple[str, ...] = "**/*") -> list[Path]:
    if root.is_file():
        return [root]
    patterns = (pattern,) if isinstance(pattern, str) else pattern
    return sorted({p for pat in patterns for p in root.glob(pat)
                   if p.is_file() and not p.is_symlink() and not p.name.startswith(".")})


def _pick(root: Path, rng: random.Random, pattern: str | tuple[str, ...]) -> Path:
    files = _files(root, pattern)
    assert files, f"no {pattern} in {root}"
    return rng.choice(files)


def truncate(pattern: str | tuple[str, ...]) -> Callable[[Path, random.Random], str]:
    """Cut a file short somewhere inside its content (never after its last meaningful byte)."""
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        data = path.read_bytes()
        end = len(data.rstrip()) - 1
        at = rng.randrange(0, max(end, 1))
        path.write_bytes(data[:at])
        return f"{path.name} cut to {at} of {len(data)} bytes"
    return apply


def bitflip(pattern: str | tuple[str, ...], first_bytes: int | None = None) -> Callable[[Path, random.Random], str]:
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        data = bytearray(path.read_bytes())
        span = min(len(data), first_bytes or len(data))
        where = sorted(rng.sample(range(span * 8), min(span * 8, rng.randint(1, 8))))  # distinct: each one flips
        for bit in where:
            data[bit // 8] ^= 1 << (bit % 8)
        path.write_bytes(bytes(data))
        return f"{path.name}: bits {where} flipped"
    return apply


def garbage(pattern: str | tuple[str, ...]) -> Callable[[Path, random.Random], str]:
    """Replace a file by random bytes of another length (a random file of the same length could be a
    valid uncompressed chunk)."""
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        size = path.stat().st_size
        n = rng.choice([1, 7, 64, 4096, size + 1 + rng.randrange(100)])
        n = n if n != size else n + 1
        path.write_bytes(rng.randbytes(n))
        return f"{path.name} replaced by {n} random bytes"
    return apply


def empty(pattern: str | tuple[str, ...]) -> Callable[[Path, random.Random], str]:
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        path.write_bytes(b"")
        return f"{path.name} emptied"
    return apply


def delete(pattern: str) -> Callable[[Path, random.Random], str]:
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        path.unlink()
        return f"{path.name} deleted"
    return apply


def symlink_out(pattern: str, dangling: bool | None = None) -> Callable[[Path, random.Random], str]:
    """Replace a file by a symlink to a file outside the source (or to a missing one)."""
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        missing = rng.random() < 0.5 if dangling is None else dangling
        target = root.parent / ("missing.bin" if missing else OUTSIDE)
        path.unlink()
        path.symlink_to(target)
        return f"{path.name} -> {target.name}"
    return apply


# ---------------------------------------------------------------------------------------------- value corruptions
BAD_VALUES: tuple[Any, ...] = (None, "", "x", -1, 0, 2**64, 1e308, -1e308, math.nan, math.inf, [], {}, True, [[[[]]]],
                               "../../outside.bin", "/etc/hostname", "\x1b[2J\nline two")
BAD_SHAPES: tuple[Any, ...] = ([2**40], [-1], ["x"], [2**31, 2**31], [1] * 40, 2**40, None, [1.5], [])
BAD_COUNTS: tuple[Any, ...] = (-1, 2**62, 2**40, 1.5, "7", None, math.nan, True)
# For fields read with int(): "7", 1.5 and True would be read as valid numbers.
RECORD_VALUES = tuple(v for v in BAD_VALUES + BAD_SHAPES + BAD_COUNTS if not isinstance(v, (bool, float, str)) or
                      isinstance(v, float) and not math.isfinite(v) or isinstance(v, str) and not v.isdigit())


def _walk(obj: Any, path: tuple[str, ...], rng: random.Random) -> tuple[Any, Any]:
    """(container, key) at ``path`` in a JSON value; ``*`` picks a random key or index."""
    parent, key = None, None
    for step in path:
        parent = obj
        if step == "*":
            keys = list(obj) if isinstance(obj, dict) else list(range(len(obj)))
            key = rng.choice(keys)
        else:
            key = step if isinstance(obj, dict) else int(step)
        obj = obj[key]
    return parent, key


def json_field(file: str, *paths: tuple[str, ...], values: tuple[Any, ...] = BAD_VALUES) -> Callable[[Path, random.Random], str]:
    """Set one JSON field (one of ``paths``; ``*``: a random key) to a bad value: a wrong type, NaN,
    a huge number."""
    def apply(root: Path, rng: random.Random) -> str:
        target = root / file if file else root
        doc = json.loads(target.read_text())
        path = rng.choice(paths)
        parent, key = _walk(doc, path, rng)
        value = rng.choice([v for v in values if v is _DELETE or not _same(v, parent[key])])
        if value is _DELETE:
            del parent[key]
        else:
            parent[key] = value
        target.write_text(json.dumps(doc))
        return f"{file}: {'/'.join(map(str, path))} [{key}] = {value!r}"
    return apply


_DELETE = object()


def _same(a: Any, b: Any) -> bool:
    return type(a) is type(b) and a == b


def json_any(pattern: str) -> Callable[[Path, random.Random], str]:
    """Any node of a JSON file set to a bad value or deleted."""
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, pattern)
        doc = json.loads(path.read_text())
        nodes: list[tuple[Any, Any]] = []

        def collect(obj: Any) -> None:
            items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
            for k, v in items:
                nodes.append((obj, k))
                collect(v)
        collect(doc)
        parent, key = rng.choice(nodes)
        if rng.random() < 0.2 and isinstance(parent, dict):
            del parent[key]
            did = "deleted"
        else:
            value = rng.choice(BAD_VALUES)
            parent[key] = value
            did = f"= {value!r}"
        path.write_text(json.dumps(doc))
        return f"{path.name}: [{key}] {did}"
    return apply


def text_line(file: str, edit: Callable[[str, random.Random], str]) -> Callable[[Path, random.Random], str]:
    """Change one data line of a line-based file (JSONL, CSV) by ``edit``."""
    def apply(root: Path, rng: random.Random) -> str:
        target = root / file if file else root
        lines = target.read_text().splitlines()
        i = rng.randrange(1, len(lines))
        lines[i] = edit(lines[i], rng)
        target.write_text("\n".join(lines) + "\n")
        return f"line {i + 1}: {lines[i][:80]!r}"
    return apply


def _pose_edit(line: str, rng: random.Random) -> str:
    obj = json.loads(line)
    if "t" not in obj:
        return json.dumps({"episode_seed": rng.choice([-1, 2**70, "x", None, 1.5])})
    key = rng.choice(["t", "pos", "quat", "grip", "engaged", "extra"])
    value = {"t": rng.choice([math.nan, math.inf, -1e9, 1e12, "x", None]),
             "pos": rng.choice([[1, 2], [math.nan, 0, 0], "x", [1e308, 1e308, 1e308], [[0], [0], [0]]]),
             "quat": rng.choice([[0, 0, 0, 0], [1, 0, 0], [math.nan, 0, 0, 1], "wxyz"]),
             "grip": rng.choice([2.0, -0.5, math.nan, "closed", None]),
             "engaged": rng.choice(["yes", 1, None, [True]]),
             "extra": 1}[key]
    obj[key] = value
    return json.dumps(obj)


def last_time(file: str, column: int | None) -> Callable[[Path, random.Random], str]:
    """The last sample's time a huge span after the first (what is resampled at the control rate)."""
    def apply(root: Path, rng: random.Random) -> str:
        target = root / file
        lines = target.read_text().splitlines()
        t = rng.choice([1e7, 1e12, 1e300])
        if column is None:
            obj = json.loads(lines[-1])
            obj["t"] = t
            lines[-1] = json.dumps(obj)
        else:
            cells = lines[-1].split(",")
            cells[column] = repr(t)
            lines[-1] = ",".join(cells)
        target.write_text("\n".join(lines) + "\n")
        return f"last t = {t:g}"
    return apply


def _csv_edit(line: str, rng: random.Random) -> str:
    cells = line.split(",")
    how = rng.choice(["cell", "cell", "cell", "drop", "add", "time"])
    if how == "drop":
        cells.pop(rng.randrange(len(cells)))
    elif how == "add":
        cells.append("0")
    elif how == "time":
        cells[1] = rng.choice(["1e12", "-5", "nan", "inf"])
    else:
        cells[rng.randrange(len(cells))] = rng.choice(["nan", "inf", "-inf", "", "x", "0x10", "2.0.1", "1" * 5000])
    return ",".join(cells)


def toml_key(file: str, keys: tuple[str, ...]) -> Callable[[Path, random.Random], str]:
    """Set one key of a flat TOML file to a bad value, or delete it."""
    def apply(root: Path, rng: random.Random) -> str:
        target = root / file
        doc = tomllib.loads(target.read_text())
        key = rng.choice(keys)
        value = rng.choice([_DELETE, "nope", -1, 0, 1e308, math.nan, math.inf, [], ["nope"], True, [1, 2, 3, 4, 5],
                            "/etc/hostname", "../outside.bin", "missing.xml", [math.nan, 0.0]])
        if value is _DELETE:
            doc.pop(key, None)
        else:
            doc[key] = value
        target.write_text(_toml(doc))
        return f"{file}: {key} = {'(deleted)' if value is _DELETE else repr(value)}"
    return apply


def _toml(doc: dict[str, Any]) -> str:
    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, float):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return str(v)
    return "".join(f"{k} = {value(v)}\n" for k, v in doc.items())


# ---------------------------------------------------------------------------------------------- parquet corruptions
def parquet_column(file_pattern: str, columns: dict[str, tuple[Any, ...]]) -> Callable[[Path, random.Random], str]:
    """Rewrite one column of a parquet file (``columns``: name -> bad values): another type, nulls,
    negative or huge values in its first row, or the column dropped."""
    def apply(root: Path, rng: random.Random) -> str:
        path = _pick(root, rng, file_pattern)
        table = pq.read_table(path)
        name = rng.choice([c for c in columns if c in table.column_names])
        value = rng.choice(columns[name])
        if value is _DELETE:
            table = table.drop_columns([name])
        else:
            rows = table.column(name).to_pylist()
            try:  # the first row changed, the column's type kept where the value fits it
                array = pa.array([value] + rows[1:], type=table.column(name).type)
            except (pa.ArrowException, TypeError, ValueError, OverflowError):
                array = pa.array([value] * table.num_rows) if value is not None else pa.nulls(table.num_rows)
            table = table.set_column(table.column_names.index(name), name, array)
        pq.write_table(table, path)
        return f"{path.name}: column {name} = {'(dropped)' if value is _DELETE else repr(value)}"
    return apply


# ---------------------------------------------------------------------------------------------- HDF5 corruptions
def hdf5_attack(root: Path, rng: random.Random) -> str:
    """Make a dataset of the file read from elsewhere: HDF5 external storage, an external link, a soft
    link through one, a virtual dataset, or a declared size the file's bytes cannot hold."""
    outside = root.parent / OUTSIDE
    kind = rng.choice(["external_storage", "external_link", "soft_link_out", "virtual", "huge", "huge_attr",
                       "wrong_dtype", "scalar"])
    with h5py.File(root, "a") as f:
        demo = f["data"][rng.choice(sorted(f["data"].keys()))]
        name = rng.choice(["actions", "states", "obs/" + rng.choice(sorted(demo["obs"].keys()))])
        shape, dtype = demo[name].shape, demo[name].dtype
        del demo[name]
        if kind == "external_storage":
            n = int(np.prod(shape)) * dtype.itemsize
            demo.create_dataset(name, shape=shape, dtype=dtype, external=[(str(outside), 0, n)])
        elif kind == "external_link":
            demo[name] = h5py.ExternalLink(str(outside), "/x")
        elif kind == "soft_link_out":
            f["hop"] = h5py.ExternalLink(str(outside), "/x")
            demo[name] = h5py.SoftLink("/hop")
        elif kind == "virtual":
            layout = h5py.VirtualLayout(shape=shape, dtype=dtype)
            layout[...] = h5py.VirtualSource(str(outside), "x", shape=shape)
            demo.create_virtual_dataset(name, layout)
        elif kind == "huge":
            demo.create_dataset(name, shape=(2**40, *shape[1:]), dtype=dtype, chunks=(1024, *shape[1:]))
        elif kind == "huge_attr":
            demo.create_dataset(name, shape=shape, dtype=dtype)
            demo.attrs["num_samples"] = rng.choice([2**40, -5, "many", np.arange(3)])
        elif kind == "wrong_dtype":
            demo.create_dataset(name, data=np.array([b"x"] * shape[0]))
        else:
            demo.create_dataset(name, data=1.0)
    return f"{kind} at {name}"


def hdf5_attr(root: Path, rng: random.Random) -> str:
    """A root or demo attribute of the wrong type or with bad JSON."""
    with h5py.File(root, "a") as f:
        data = f["data"]
        if rng.random() < 0.5:
            meta = json.loads(data.attrs["demo_meta"])
            parent, key = _walk(meta, rng.choice([("store_meta", "fps"), ("store_meta", "features", "*", "shape"),
                                                  ("store_meta", "features", "*", "dtype"), ("keys", "*"),
                                                  ("episode_columns", "*")]), rng)
            value = rng.choice(BAD_VALUES + BAD_SHAPES)
            parent[key] = value
            data.attrs["demo_meta"] = json.dumps(meta)
            return f"demo_meta [{key}] = {value!r}"
        demo = data[rng.choice(sorted(data.keys()))]
        attr = rng.choice(["episode.success", "episode.seed", "episode.task", "num_samples"])
        value = rng.choice([np.arange(3), "x", 2**62, -1, np.float64("nan")])
        demo.attrs[attr] = value
        return f"{demo.name} attr {attr} = {value!r}"


# ---------------------------------------------------------------------------------------------- LeRobot path tricks
def lerobot_path(root: Path, rng: random.Random) -> str:
    """data_path leading out of the dataset (``..``, absolute, a format-string trick) or a symlink out."""
    info_path = root / "meta/info.json"
    info = json.loads(info_path.read_text())
    trick = rng.choice(["dotdot", "absolute", "attribute", "width", "unknown_field", "link_data", "link_info",
                        "link_meta", "video"])
    if trick in ("link_data", "link_info", "link_meta"):
        path = {"link_data": root / "data/chunk-000/file-000.parquet", "link_info": info_path,
                "link_meta": root / "meta"}[trick]
        target = root.parent / rng.choice([OUTSIDE, "missing.bin"])
        shutil.rmtree(path) if path.is_dir() else path.unlink()
        path.symlink_to(target)
        return f"{trick}: {path.name} -> {target.name}"
    info["data_path"] = {
        "dotdot": "../" + rng.choice([OUTSIDE, "missing.bin"]) + "?{chunk_index}{file_index}",
        "absolute": str(root.parent / OUTSIDE) + "{chunk_index}{file_index}",
        "attribute": "data/{chunk_index.__class__}/{file_index}.parquet",
        "width": "data/chunk-{chunk_index:999999999d}/file-{file_index:03d}.parquet",
        "unknown_field": "data/{secret}/{file_index}.parquet",
        "video": info["data_path"],
    }[trick]
    if trick == "video":
        info["video_path"] = "../../videos/{video_key}/{episode_index}.mp4"
    elif trick in ("dotdot", "absolute"):  # the literal names, not templates that format to something else
        info["data_path"] = info["data_path"].replace("?{chunk_index}{file_index}", "").replace("{chunk_index}{file_index}", "")
    info_path.write_text(json.dumps(info))
    return f"data_path {info['data_path']!r}"


# ---------------------------------------------------------------------------------------------- the sources
def store_source() -> Source:
    commands: dict[str, Command] = {
        "info --check": lambda s, o: ["info", str(s), "--check"],
        "train": lambda s, o: ["train", str(s), "--out", str(o / "run"), "--steps", "2", "--batch-size", "4",
                               "--warmup", "1", "--policy-opt", "hidden=8,8", "--val-fraction", "0"],
        "curate": lambda s, o: ["curate", str(s), "--out", str(o / "c.zarr"), "--show", "none"],
        "convert": lambda s, o: ["convert", str(s), "--to", "ee7", "--out", str(o / "c.zarr")],
        "export": lambda s, o: ["export", str(s), "--format", "lerobot", "--out", str(o / "lr")],
    }
    chunks = "data/*/c/**/*"
    meta = "**/zarr.json"
    flip_why = "a flipped bit in stored values or metadata text can leave a valid store with other values"
    return Source("store", commands, (
        Corruption("truncate_meta", truncate(meta)),
        Corruption("truncate_table", truncate("episodes.parquet")),
        Corruption("truncate_chunk", truncate(chunks), command="info --check"),
        Corruption("truncate_chunk_any", truncate(chunks), ANY, "a shorter chunk reads as fill values past its end "
                   "unless checksums are verified (info --check)"),
        Corruption("bitflip", bitflip("**/*"), ANY, flip_why),
        # The first row of a chunk is always a committed frame (spare rows past the last episode are not data).
        Corruption("bitflip_chunk_checked", bitflip(chunks, first_bytes=4), command="info --check"),
        Corruption("garbage_meta", garbage(meta)),
        Corruption("garbage_table", garbage("episodes.parquet")),
        Corruption("empty_meta", empty(meta)),
        Corruption("delete_meta", delete(meta)),
        Corruption("delete_table", delete("episodes.parquet")),
        Corruption("json_any", json_any(meta), ANY, "descriptive fields (units, descriptions, provenance) may hold anything"),
        Corruption("fps", json_field("zarr.json", ("attributes", "demo", "fps"),
                                     values=(None, "x", -1, 0, 2**64, 1e308, -1e308, math.nan, math.inf, [], {}))),
        Corruption("feature_shape", json_field("zarr.json", ("attributes", "demo", "features", "*", "shape"),
                                               values=tuple(v for v in BAD_SHAPES if v != [1.5]))),  # read as int(1.5)
        Corruption("feature_dtype", json_field("zarr.json", ("attributes", "demo", "features", "*", "dtype"),
                                               values=("int32", "float64", "object", "x", None, "<U5", "complex64"))),
        Corruption("array_shape", _array_json(("shape",), BAD_SHAPES)),
        Corruption("array_dtype", _array_json(("data_type",), ("int32", "float64", "x", None, 7))),
        Corruption("table_column", parquet_column("episodes.parquet", {
            "length": (-1, 0, 2**40, None, "x", 1.5, _DELETE), "start": (-1, 2**40, None, "x", _DELETE),
            "success": (None, "x", 2**40, _DELETE), "seed": ("x",), "crc32": (None, "x", _DELETE)})),
        Corruption("symlink_chunk", symlink_out(chunks), command="info --check"),
    ))


def _array_json(path: tuple[str, ...], values: tuple[Any, ...]) -> Callable[[Path, random.Random], str]:
    def apply(root: Path, rng: random.Random) -> str:
        array = rng.choice(sorted(p.parent.name for p in root.glob("data/*/zarr.json")))
        return json_field(f"data/{array}/zarr.json", path, values=values)(root, rng)
    return apply


def robot_source() -> Source:
    keys = ("mjcf", "arm_joints", "gripper_actuator", "gripper_range", "ee_site", "base_body", "home_key",
            "max_joint_velocity", "ee_site_pos", "gravcomp", "name")
    command: dict[str, Command] = {
        "collect --robot": lambda s, o: ["collect", "--task", "reach", "--episodes", "1", "--workers", "0",
                                         "--robot", str(s / "robot.toml"), "--out", str(o / "c.zarr")],
    }
    return Source("robot", command, (
        Corruption("toml_key", toml_key("robot.toml", keys), ANY, "a key may change to another valid value "
                   "(a name, gravcomp, max_joint_velocity)"),
        Corruption("truncate_toml", truncate("robot.toml"), ANY, "a TOML file cut after a complete line is valid TOML"),
        Corruption("garbage_toml", garbage("robot.toml")),
        Corruption("truncate_mjcf", truncate("*.xml")),
        Corruption("garbage_mjcf", garbage("*.xml")),
        Corruption("empty_mjcf", empty("*.xml")),
        Corruption("bitflip_mjcf", bitflip("*.xml"), ANY, "a flipped bit in a number of the MJCF is another robot"),
    ))


def vr_source() -> Source:
    command: dict[str, Command] = {
        "collect --source vr": lambda s, o: ["collect", "--source", "vr", "--task", "reach", "--input", str(s / "POSES.jsonl"),
                                             "--scale", str(1 / 1.3), "--out", str(o / "c.zarr")],
    }
    return Source("vr", command, (
        Corruption("pose_value", text_line("POSES.jsonl", _pose_edit)),
        Corruption("duration", last_time("POSES.jsonl", None)),
        Corruption("truncate", truncate("POSES.jsonl"), ANY, "a pose file cut at a line end is a shorter recording"),
        Corruption("garbage", garbage("POSES.jsonl")),
        Corruption("empty", empty("POSES.jsonl")),
        Corruption("bitflip", bitflip("POSES.jsonl"), ANY, "a flipped bit in a digit is another pose"),
    ))


def kinesthetic_source() -> Source:
    command: dict[str, Command] = {
        "collect --source kinesthetic": lambda s, o: ["collect", "--source", "kinesthetic", "--task", "reach", "--input",
                                                      str(s / "JOINTS.csv"), "--out", str(o / "c.zarr")],
    }
    return Source("kinesthetic", command, (
        Corruption("cell", text_line("JOINTS.csv", _csv_edit)),
        Corruption("duration", last_time("JOINTS.csv", 1)),
        Corruption("truncate", truncate("JOINTS.csv"), ANY, "a CSV cut at a line end (or inside a number) is still a recording"),
        Corruption("garbage", garbage("JOINTS.csv")),
        Corruption("empty", empty("JOINTS.csv")),
        Corruption("bitflip", bitflip("JOINTS.csv"), ANY, "a flipped bit in a digit is another joint angle"),
    ))


def run_source() -> Source:
    command: dict[str, Command] = {"eval": lambda s, o: ["eval", str(s), "--episodes", "1", "--json", str(o / "e.json")]}
    read = "[rp]*.[js]*"  # run.json and policy.safetensors: what eval reads
    return Source("run", command, (
        Corruption("truncate", truncate(read)),
        Corruption("garbage", garbage(read)),
        Corruption("empty", empty(read)),
        Corruption("delete", delete(read)),
        Corruption("bitflip", bitflip(read), ANY, "a flipped bit in a weight is another policy"),
        Corruption("run_json", json_any("run.json"), ANY, "descriptive fields (versions, the command, data) may hold anything"),
        Corruption("policy_record", json_field("run.json", ("policy", "spec", "*"), ("policy", "obs", "*"),
                                               ("policy", "config", "hidden"), ("policy", "execution", "execute"),
                                               ("policy", "algo"), ("policy", "relative_actions", "*"),
                                               values=RECORD_VALUES)),
        Corruption("symlink_out", symlink_out("policy.safetensors")),
    ))


def train_state_source() -> Source:
    command: dict[str, Command] = {
        # the store the run was trained on (resume checks the path; the store is only read)
        "train --resume": lambda s, o: ["train", json.loads((s / "run.json").read_text())["data"]["path"], "--out", str(s),
                                        "--resume", "--steps", "3",
                                        "--batch-size", "4", "--warmup", "1", "--policy-opt", "hidden=8,8",
                                        "--val-fraction", "0"],
    }
    return Source("train_state", command, (
        Corruption("truncate", truncate("train_state.pt")),
        Corruption("garbage", garbage("train_state.pt")),
        Corruption("empty", empty("train_state.pt")),
    ))


def lerobot_source() -> Source:
    command: dict[str, Command] = {"import lerobot": lambda s, o: ["import", str(s), "--format", "lerobot",
                                                                    "--out", str(o / "i.zarr")]}
    parquet = "**/*.parquet"
    read = ("meta/info.json", parquet)  # not meta/stats.json: an import recomputes nothing from it
    return Source("lerobot", command, (
        Corruption("path_trick", lerobot_path),
        Corruption("truncate", truncate(read)),
        Corruption("garbage", garbage(read)),
        Corruption("empty", empty(read)),
        Corruption("bitflip", bitflip("**/*"), ANY, "a flipped bit in a parquet value or in info.json text can leave a "
                   "valid dataset"),
        Corruption("info_any", json_any("meta/info.json"), ANY, "descriptive fields (names, robot_type, extras) may hold anything"),
        Corruption("info_numbers", json_field("meta/info.json", ("*",), values=BAD_COUNTS + BAD_SHAPES), ANY,
                   "a top-level key demo does not read (chunks_size, splits) may hold anything"),
        Corruption("feature_shape", json_field("meta/info.json", ("features", "*", "shape"), values=BAD_SHAPES), ANY,
                   "a structural column's declared shape (timestamp, index) is not read"),
        Corruption("episode_column", parquet_column("meta/episodes/**/*.parquet", dict.fromkeys((
            "length", "episode_index", "data/chunk_index", "data/file_index", "dataset_from_index", "dataset_to_index",
            "demo/success", "demo/seed"), BAD_COUNTS + (_DELETE,))), ANY,
            "a dropped locator column is allowed (every data file is read instead)"),
        Corruption("data_column", parquet_column("data/**/*.parquet", {
            **dict.fromkeys(("episode_index", "frame_index", "action"), BAD_COUNTS + (_DELETE,)),
            "index": BAD_COUNTS})),  # optional: a dataset without it is valid
        Corruption("symlink_parquet", symlink_out(parquet)),
    ))


def robomimic_source() -> Source:
    command: dict[str, Command] = {"import robomimic": lambda s, o: ["import", str(s), "--format", "robomimic",
                                                                      "--out", str(o / "i.zarr")]}
    return Source("robomimic", command, (
        Corruption("attack", hdf5_attack),
        Corruption("attr", hdf5_attr, ANY, "a per-episode attribute may change to another valid value"),
        Corruption("truncate", truncate("*")),
        Corruption("garbage", garbage("*")),
        Corruption("bitflip", bitflip("*"), ANY, "a flipped bit in a stored value is another value"),
    ))


SOURCES: tuple[Source, ...] = (store_source(), robot_source(), vr_source(), kinesthetic_source(), run_source(),
                               train_state_source(), lerobot_source(), robomimic_source())


def pairs() -> list[tuple[Source, Corruption]]:
    return [(s, c) for s in SOURCES for c in s.corruptions]


def cases(count: int, seed: int = 0) -> list[Case]:
    """``count`` cases: corruption ``i mod pairs``, a seed and a command drawn from ``(seed, i)``."""
    layout = pairs()
    out = []
    for i in range(count):
        source, corruption = layout[i % len(layout)]
        rng = random.Random(f"{seed}-{i}")
        command = corruption.command or rng.choice(sorted(source.commands))
        out.append(Case(i, source, corruption, command, rng.randrange(2**32)))
    return out


# ---------------------------------------------------------------------------------------------- building the sources
def build_sources(folder: Path, main: Callable[[list[str]], int]) -> dict[str, Path]:
    """Write every pristine source under ``folder`` with ``demo`` itself (``main``); name -> path."""
    from demo.collect.human_files import write_human_files
    from demo.sim.robot import ASSETS

    folder.mkdir(parents=True, exist_ok=True)
    paths = {name: folder / name for name in ("store", "robot", "vr", "kinesthetic", "run", "lerobot")}
    paths["robomimic"] = folder / "robomimic.hdf5"
    paths["train_state"] = folder / "train_state"
    store = paths["store"]
    assert main(["collect", "--task", "reach", "--episodes", "2", "--workers", "0", "--seed", "3", "--out", str(store)]) == 0
    assert main(store_source().commands["train"](store, folder)) == 0
    shutil.move(str(folder / "run"), paths["run"])
    shutil.copytree(paths["run"], paths["train_state"])
    assert main(["export", str(store), "--format", "lerobot", "--out", str(paths["lerobot"])]) == 0
    assert main(["export", str(store), "--format", "robomimic", "--out", str(paths["robomimic"])]) == 0
    paths["robot"].mkdir()
    shutil.copy(ASSETS / "panda.toml", paths["robot"] / "robot.toml")
    shutil.copy(ASSETS / "panda.xml", paths["robot"] / "panda.xml")
    human = folder / "human"
    write_human_files(human, task="reach", episodes=1, seed=5)
    paths["vr"].mkdir()
    poses = (human / "POSES.jsonl").read_text().splitlines()
    (paths["vr"] / "POSES.jsonl").write_text("\n".join(poses[:31]) + "\n")  # a header and half a second at 60 Hz
    paths["kinesthetic"].mkdir()
    rows = (human / "JOINTS.csv").read_text().splitlines()
    (paths["kinesthetic"] / "JOINTS.csv").write_text("\n".join(rows[:51]) + "\n")  # half a second at 100 Hz
    return paths


# ---------------------------------------------------------------------------------------------- running a case
@dataclass
class Outcome:
    rc: int
    stderr: str
    stdout: str
    changed: list[str]  # files of the source (or outside it) whose bytes changed
    did: str


def fingerprint(*roots: Path) -> dict[str, str]:
    """sha256 of every file under ``roots`` (symlinks by their target name, not followed)."""
    out: dict[str, str] = {}
    for root in roots:
        if not os.path.lexists(root):
            continue
        paths = [root] if not root.is_dir() or root.is_symlink() else [root, *sorted(root.rglob("*"))]
        for p in paths:
            if p.is_symlink():
                out[str(p)] = "link:" + os.readlink(p)
            elif p.is_file():
                out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def prepare(case: Case, sources: dict[str, Path], work: Path) -> tuple[Path, str, list[str]]:
    """Copy the case's source into ``work``, corrupt it; return (its path, what was done, argv)."""
    pristine = sources[case.source.name]
    src = work / pristine.name
    (work / OUTSIDE).write_bytes(np.arange(4096, dtype=np.uint8).tobytes())
    if pristine.is_dir():
        shutil.copytree(pristine, src, symlinks=True)
    else:
        shutil.copy2(pristine, src)
    did = case.corruption.apply(src, random.Random(case.seed))
    out = work / "out"
    out.mkdir()
    return src, did, case.source.commands[case.command](src, out)


def run_case(case: Case, sources: dict[str, Path], work: Path, main: Callable[[list[str]], int],
             read: Callable[[], tuple[str, str]]) -> Outcome:
    """Run ``demo`` on a corrupted copy; ``read()`` returns (stdout, stderr) captured since the last call."""
    src, did, argv = prepare(case, sources, work)
    watched = [src, work / OUTSIDE] + ([sources["store"]] if case.source.name == "train_state" else [])
    before = fingerprint(*watched)
    read()
    rc = main(argv)
    stdout, stderr = read()
    after = fingerprint(*watched)
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    return Outcome(rc, stderr, stdout, changed, did)


def problems(case: Case, outcome: Outcome) -> list[str]:
    """What breaks the invariant: a traceback, not exactly one ``error: `` line on failure, an
    unexpected success, a changed source byte (a resumed run rewrites its own state: only on failure)."""
    found = []
    lines = [line for line in outcome.stderr.splitlines() if line.strip()]
    if "Traceback" in outcome.stderr or "Traceback" in outcome.stdout:
        found.append("traceback")
    if outcome.rc != 0:
        if len(lines) != 1 or not lines[0].startswith("error: "):
            found.append(f"stderr is not one 'error: ' line: {lines[:4]}")
        elif "run with --debug" in lines[0]:
            found.append(f"unexpected exception, not a named problem: {lines[0]}")
    elif case.corruption.expect == FAIL:
        found.append("exit 0 on input that must be refused")
    if outcome.changed and not (outcome.rc == 0 and case.source.name == "train_state"):
        found.append(f"source changed: {outcome.changed[:3]}")
    return found
