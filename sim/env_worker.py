"""A Gymnasium environment served over stdin/stdout to :mod:`demo.sim.process_env`, in another interpreter.

Run as a script by the interpreter that has the environment's packages (``python env_worker.py``): it
imports nothing of ``demo`` (that interpreter need not have it), only the standard library, numpy and
gymnasium. Its stdout carries the protocol alone; whatever the environment prints goes to stderr.

Messages, both ways: ``<u32 header length> <u32 array count> <header: UTF-8 JSON> (<u64 length> <.npy
bytes>)*``. In the JSON, an array is ``{"$array": i}``, the i-th ``.npy`` blob (read with
``allow_pickle=False``: no object arrays, no code). Requests: ``make`` (``name``, ``options``),
``reset`` (``seed``), ``step`` (``action``), ``close``. Every reply is ``{"ok": ...}`` or ``{"error":
"one line"}``: an exception in the environment is answered, never fatal.

``name``: a Gymnasium id (``namespace/Env-v0``: the ``namespace`` module is imported first, as gym-aloha's
and other packages register their environments on import), ``module:id`` (the module imported first) or
``module:factory`` (a function returning the environment).
"""

from __future__ import annotations

import importlib
import io
import json
import struct
import sys
from typing import Any, BinaryIO

import numpy as np

HEADER = struct.Struct("<II")
BLOB = struct.Struct("<Q")
MAX_HEADER = 1 << 24  # 16 MiB of JSON
MAX_BLOB = 1 << 31  # 2 GiB per array


def write_message(stream: BinaryIO, message: Any) -> None:
    """Send ``message`` (JSON-able, with numpy arrays anywhere inside) as one frame."""
    blobs: list[bytes] = []

    def pack(value: Any) -> Any:
        if isinstance(value, np.ndarray):
            buffer = io.BytesIO()
            np.save(buffer, np.ascontiguousarray(value), allow_pickle=False)
            blobs.append(buffer.getvalue())
            return {"$array": len(blobs) - 1}
        if isinstance(value, np.generic):
            return value.item()
        if isinstance(value, dict):
            return {str(k): pack(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [pack(v) for v in value]
        if value is None or isinstance(value, (bool, int, float, str)):
            return value
        return str(value)  # an info entry of another type: its text

    header = json.dumps(pack(message)).encode()
    stream.write(HEADER.pack(len(header), len(blobs)) + header)
    for blob in blobs:
        stream.write(BLOB.pack(len(blob)) + blob)
    stream.flush()


def read_message(stream: BinaryIO) -> Any:
    """One frame from ``stream``; EOFError when it ended (the other side is gone)."""
    head = _read(stream, HEADER.size)
    size, count = HEADER.unpack(head)
    if size > MAX_HEADER:
        raise ValueError(f"a message header of {size} bytes (at most {MAX_HEADER})")
    header = json.loads(_read(stream, size))
    arrays = []
    for _ in range(count):
        (n,) = BLOB.unpack(_read(stream, BLOB.size))
        if n > MAX_BLOB:
            raise ValueError(f"an array of {n} bytes (at most {MAX_BLOB})")
        arrays.append(np.load(io.BytesIO(_read(stream, n)), allow_pickle=False))

    def unpack(value: Any) -> Any:
        if isinstance(value, dict):
            if set(value) == {"$array"}:
                return arrays[int(value["$array"])]
            return {k: unpack(v) for k, v in value.items()}
        if isinstance(value, list):
            return [unpack(v) for v in value]
        return value

    return unpack(header)


def _read(stream: BinaryIO, n: int) -> bytes:
    data = stream.read(n)
    if data is None or len(data) < n:
        raise EOFError("the stream ended")
    return data


def describe_space(space: Any) -> dict[str, Any]:
    """A ``Box`` or ``Dict`` of them as JSON (with arrays): what the proxy rebuilds."""
    import gymnasium

    if isinstance(space, gymnasium.spaces.Box):
        return {"type": "Box", "low": space.low, "high": space.high, "dtype": np.dtype(space.dtype).str}
    if isinstance(space, gymnasium.spaces.Dict):
        return {"type": "Dict", "spaces": {k: describe_space(v) for k, v in space.spaces.items()}}
    return {"type": type(space).__name__}  # refused by the proxy, by name


def make(name: str, options: dict[str, Any]) -> Any:
    import gymnasium

    module, sep, attr = name.rpartition(":")
    if sep:
        factory = getattr(importlib.import_module(module), attr, None)
        if callable(factory) and attr not in gymnasium.registry:
            return factory(**options)
        name = attr
    namespace = name.partition("/")[0] if "/" in name else None
    if namespace and name not in gymnasium.registry:
        importlib.import_module(namespace)
    return gymnasium.make(name, **options)


def serve(inp: BinaryIO, out: BinaryIO) -> None:
    env = None
    while True:
        try:
            request = read_message(inp)
        except EOFError:
            break
        command = request.get("cmd")
        try:
            if command == "make":
                env = make(request["name"], request.get("options") or {})
                spec = getattr(env, "spec", None)
                reply = {"observation_space": describe_space(env.observation_space),
                         "action_space": describe_space(env.action_space),
                         "render_fps": (env.metadata or {}).get("render_fps"),
                         "max_episode_steps": getattr(spec, "max_episode_steps", None),
                         "horizon": getattr(env.unwrapped, "horizon", None),
                         "instruction": getattr(env.unwrapped, "instruction", None),
                         "action_names": getattr(env.unwrapped, "action_names", None),
                         "action_units": getattr(env.unwrapped, "action_units", None),
                         "gripper_command": getattr(env.unwrapped, "gripper_command", None)}
            elif command == "reset":
                obs, info = env.reset(seed=request.get("seed"))
                reply = {"obs": obs, "info": info}
            elif command == "step":
                obs, reward, terminated, truncated, info = env.step(request["action"])
                reply = {"obs": obs, "reward": float(reward), "terminated": bool(terminated),
                         "truncated": bool(truncated), "info": info}
            elif command == "close":
                if env is not None:
                    env.close()
                write_message(out, {"ok": True})
                break
            else:
                raise ValueError(f"unknown request {command!r}")
            write_message(out, {"ok": reply})
        except Exception as exc:  # noqa: BLE001 - answered to the proxy, which raises it in one line
            text = " ".join(str(exc).split()) or type(exc).__name__
            write_message(out, {"error": f"{type(exc).__name__}: {text}"[:400]})


def main() -> None:
    protocol = sys.stdout.buffer
    sys.stdout = sys.stderr  # the environment's prints must not corrupt the protocol
    serve(sys.stdin.buffer, protocol)


if __name__ == "__main__":
    main()
