"""Camera images for observations: one offscreen renderer per image size, closed with the env.

Cameras are given as ``(name, width, height)`` or ``"NAME@WIDTHxHEIGHT"`` (pixels; images are uint8 [height, width, 3]); the scene defines ``front``, ``side``, ``top`` (fixed,
looking at the workspace) and ``wrist`` (on the EE). Headless rendering needs ``MUJOCO_GL=egl``
set before mujoco is imported (``demo.sim`` sets it when unset). Shadows and MSAA are off in the
scene (``shadowsize = 0``, ``offsamples = 0``): about 29 ms per 128x128 frame under llvmpipe.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.scene import CAMERA_NAMES

DEFAULT_SIZE = 128


def parse_camera(spec: str, where: object = "cameras") -> tuple[str, int, int]:
    """``"NAME@WIDTHxHEIGHT"`` (e.g. ``front@128x128``) -> (name, width, height)."""
    match = re.fullmatch(r"([A-Za-z0-9_\-]+)@(\d+)x(\d+)", spec)
    if not match:
        raise DemoError(where, f"{spec!r} is not NAME@WIDTHxHEIGHT (e.g. front@128x128)")
    return match.group(1), int(match.group(2)), int(match.group(3))


def parse_cameras(cameras: Sequence[Any]) -> "CameraSet":
    specs: list[tuple[str, int, int]] = []
    for c in cameras:
        if isinstance(c, str) and "@" in c:
            name, w, h = parse_camera(c)
        elif isinstance(c, str):
            name, h, w = c, DEFAULT_SIZE, DEFAULT_SIZE
        else:
            try:
                name, w, h = str(c[0]), int(c[1]), int(c[2])
            except (TypeError, ValueError, IndexError):
                raise DemoError("cameras", f"expected (name, width, height), got {c!r}") from None
        if name not in CAMERA_NAMES:
            raise DemoError("cameras", f"unknown camera '{name}' (known: {', '.join(CAMERA_NAMES)})")
        if not (8 <= h <= 2048 and 8 <= w <= 2048):
            raise DemoError("cameras", f"camera '{name}' size {w}x{h} (WxH) out of range 8..2048")
        if any(s[0] == name for s in specs):
            raise DemoError("cameras", f"camera '{name}' given twice")
        specs.append((name, h, w))
    return CameraSet(specs)


class CameraSet:
    """Renderers for the requested cameras; ``specs`` holds (name, height, width).

    Cameras of one size share a renderer. Per frame each camera costs ``update_scene`` + ``render``
    and nothing else (``demo bench render`` holds collection to that): the ``MjvCamera`` of each
    camera is made once at :meth:`open`, not looked up by name every frame.
    """

    def __init__(self, specs: list[tuple[str, int, int]]):
        self.specs = specs
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._views: list[tuple[str, mujoco.Renderer, mujoco.MjvCamera]] = []  # (obs key, renderer, camera)

    def max_size(self) -> tuple[int, int]:
        """(width, height) the offscreen buffer must hold."""
        return (max((w for _, _, w in self.specs), default=0), max((h for _, h, _ in self.specs), default=0))

    def open(self, model: mujoco.MjModel) -> None:
        if self.specs:
            _headless_gl()
        self._views.clear()
        for name, h, w in self.specs:
            if (h, w) not in self._renderers:
                try:
                    self._renderers[(h, w)] = mujoco.Renderer(model, height=h, width=w)
                except Exception as exc:  # no GL context: say how to get one
                    self.close()
                    raise DemoError("cameras", f"cannot render ({exc}); set MUJOCO_GL=egl for headless rendering") from None
            camera = mujoco.MjvCamera()
            camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
            camera.fixedcamid = model.camera(name).id
            self._views.append((f"obs.image_{name}", self._renderers[(h, w)], camera))

    def render(self, data: mujoco.MjData, out: dict[str, np.ndarray]) -> None:
        """Each camera's image of ``data`` into ``out[obs.image_<name>]`` (a new uint8 [H, W, 3] array)."""
        for key, renderer, camera in self._views:
            renderer.update_scene(data, camera=camera)
            out[key] = renderer.render()

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
        self._views.clear()


def _headless_gl() -> None:
    """Use EGL when mujoco was imported (GLFW chosen) before ``demo.sim`` set MUJOCO_GL, headless.

    mujoco picks its GL backend when first imported; a process that imported it before
    ``demo.sim`` and has no display would otherwise fail to render.
    """
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    if os.environ.get("MUJOCO_GL", "egl").lower() != "egl":
        return
    try:
        from mujoco.rendering.classic import gl_context  # deferred: only when rendering headless
    except ImportError:
        return
    current = getattr(gl_context, "GLContext", None)
    if current is None or not getattr(current, "__module__", "").startswith("mujoco.glfw"):
        return
    try:
        from mujoco.egl import GLContext as EGLContext  # deferred: binds PyOpenGL to EGL, only when GLFW was chosen
    except Exception:  # PyOpenGL already bound to another platform: keep GLFW, fail with a hint
        return
    gl_context.GLContext = EGLContext
