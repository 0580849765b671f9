"""``demo serve RUN``: a trained policy behind a WebSocket, answering observation -> action chunk.

One connection is one robot: it has its own observation history (the policy's ``n_obs`` frames) and
sampling generator. The server binds 127.0.0.1 unless told otherwise (it runs whatever observations
it is sent through a network of the user's choosing; there is no authentication). ``delay_s`` adds an
inference delay, to test a client against a slower machine.
"""

from __future__ import annotations

import ipaddress
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np
import torch
from websockets.exceptions import ConnectionClosed
from websockets.sync.server import Server, ServerConnection, serve

from demo.deploy.protocol import decode, encode, pack_array, unpack_array
from demo.errors import DemoError
from demo.policies.checkpoint import load_bundle


@dataclass
class ServerConfig:
    run: str
    host: str = "127.0.0.1"
    port: int = 8765  # 0: a free one
    device: str = "cpu"
    delay_s: float = 0.0  # added to every inference (tests)
    expose: bool = False  # allow a host other than loopback (there is no authentication)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class PolicyServer:
    """The policy of ``config.run``, served; :meth:`start` in a thread, or :meth:`serve_forever`."""

    def __init__(self, config: ServerConfig, log: Callable[[str], None] = lambda line: None):
        if not is_loopback(config.host) and not config.expose:
            raise DemoError("--host", f"{config.host} is reachable from other machines and the server has no "
                                      "authentication: pass --expose to serve there anyway")
        self.config = config
        self.log = log  # one line per problem with a client's message (the server keeps serving)
        self.bundle = load_bundle(config.run, config.device)
        self.lock = threading.Lock()  # one inference at a time: torch on a few threads
        try:
            self.server: Server = serve(self._handle, config.host, config.port, max_size=2**26)
        except OSError as exc:
            raise DemoError(f"{config.host}:{config.port}", f"cannot listen ({exc.strerror or exc})") from None
        self.thread: threading.Thread | None = None
        host, port = self.server.socket.getsockname()[:2]
        self.url = f"ws://{host}:{port}"  # the port it got (port 0: a free one)

    def start(self) -> "PolicyServer":
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()
        return self

    def serve_forever(self) -> None:
        self.server.serve_forever()

    def close(self) -> None:
        self.server.shutdown()
        if self.thread is not None:
            self.thread.join(timeout=5)

    def _handle(self, ws: ServerConnection) -> None:
        actor = self.bundle.actor()
        who = "{}:{}".format(*ws.remote_address[:2]) if ws.remote_address else "a client"
        try:
            for raw in ws:
                try:
                    ws.send(encode(self._answer(actor, decode(raw if isinstance(raw, bytes) else raw.encode()))))
                except (ValueError, KeyError, TypeError, IndexError, DemoError, msgspec.MsgspecError) as exc:
                    problem = f"{type(exc).__name__}: {exc}" if not isinstance(exc, DemoError) else str(exc)
                    self.log(f"client {who}: {problem}")
                    ws.send(encode({"type": "error", "problem": problem}))
        except ConnectionClosed:
            self.log(f"client {who}: disconnected")

    def _answer(self, actor: Any, message: dict[str, Any]) -> dict[str, Any]:
        if message["type"] == "reset":
            actor.reset(int(message.get("seed", 0)))
            return {"type": "ready", "prefix_steps": self.bundle.policy.spec.prefix}
        if message["type"] != "obs":
            raise ValueError(f"unknown message type {message['type']!r}")
        frame = {k: unpack_array(v) for k, v in message["frame"].items()}
        spec = self.bundle.obs_spec
        for key, shape in (*zip(spec.source_keys, (None,) * len(spec.source_keys)), *zip(spec.images, spec.image_shapes)):
            if key not in frame:
                raise ValueError(f"the observation has no {key}")
            if shape is not None and tuple(frame[key].shape) != tuple(shape):
                raise ValueError(f"{key} is {tuple(frame[key].shape)}, the policy reads {tuple(shape)}")
            if not np.isfinite(frame[key]).all():
                raise ValueError(f"{key} holds non-finite values")
        # actions the robot has committed to (demo.policies.prefix), checked by the actor
        prefix = unpack_array(message["prefix"]) if "prefix" in message else None
        start = time.perf_counter()
        with self.lock, torch.inference_mode():
            chunk = actor.chunk(frame, prefix)
        if self.config.delay_s:
            time.sleep(self.config.delay_s)
        return {"type": "chunk", "seq": message["seq"], "t_obs": message["t_obs"], "chunk": pack_array(chunk),
                "infer_ms": 1000 * (time.perf_counter() - start)}

