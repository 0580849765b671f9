"""The wire format of :mod:`demo.deploy`: msgpack messages (msgspec) over a WebSocket.

Arrays travel as ``[dtype, shape, raw bytes]`` (little-endian, C order), so a 64x64 camera image costs
its 12 KiB and no base64. Messages, client to server:

- ``{"type": "reset", "seed": int}``: a new episode (clears the observation history), answered by
  ``{"type": "ready", "prefix_steps": int}`` (how many committed actions the policy continues,
  :mod:`demo.policies.prefix`; 0: it ignores them);
- ``{"type": "obs", "seq": int, "t_obs": float, "frame": {key: array}[, "prefix": array [d, A]]}``: an
  observation taken at ``t_obs`` (the client's clock, s), with the actions already committed for its step
  and the ``d - 1`` after it, answered by
  ``{"type": "chunk", "seq": int, "t_obs": float, "chunk": array [H, A] float32, "infer_ms": float}``.

Errors come back as ``{"type": "error", "problem": str}``.
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder()


def pack_array(a: np.ndarray) -> list[Any]:
    a = np.ascontiguousarray(a)
    return [a.dtype.str, list(a.shape), a.tobytes()]


def unpack_array(item: Any) -> np.ndarray:
    dtype, shape, raw = item
    return np.frombuffer(raw, dtype=np.dtype(dtype)).reshape(shape)


def encode(message: dict[str, Any]) -> bytes:
    return _encoder.encode(message)


def decode(raw: bytes) -> dict[str, Any]:
    message = _decoder.decode(raw)
    if not isinstance(message, dict) or "type" not in message:
        raise ValueError("not a demo.deploy message")
    return message
