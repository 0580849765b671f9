"""Videos of evaluation episodes: re-rendered from their recorded simulator states, tiled in a grid.

Rollouts record ``sim.state`` per frame; rendering happens afterwards in one process on a separate
environment with the scene's ``front`` camera (offscreen, ``MUJOCO_GL=egl``, shadows and MSAA off
in the scene, ``size`` x ``size`` px per episode, every second frame), so evaluation workers never
need a GL context. Each tile gets a green (success) or red (failure) border; finished episodes hold
their last frame. Written with imageio: GIF through Pillow; MP4 only where an ffmpeg/pyav plugin is
installed (it is not in the default environment), else a clear error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.jsonio import replace_atomically
from demo.sim import make_env

CAMERA = "front"
FRAME_STRIDE = 2
BORDER = 3


def write_video(
    path: str | Path,
    outcomes: Sequence[Any],  # EpisodeOutcome with .states and .success
    task: str,
    options: dict[str, Any],
    robot: str | None,
    fps: float = 20.0,
    size: int = 128,
) -> dict[str, Any]:
    path = Path(path)
    if path.suffix.lower() not in (".gif", ".mp4"):
        raise DemoError(path, "video must be .gif or .mp4")
    if not outcomes:
        raise DemoError(path, "no episodes recorded for the video")
    env = make_env(task, robot=robot, cameras=((CAMERA, size, size),), **options)
    try:
        tiles = [_render_episode(env, o.states[::FRAME_STRIDE], size, bool(o.success)) for o in outcomes]
    finally:
        env.close()
    frames = _grid(tiles)
    _write(path, frames, fps / FRAME_STRIDE)
    return {"path": str(path), "episodes": len(tiles), "frames": len(frames), "size": list(frames[0].shape[:2])}


def _render_episode(env: Any, states: np.ndarray, size: int, success: bool) -> np.ndarray:
    colour = np.array([40, 200, 70] if success else [220, 50, 40], dtype=np.uint8)
    out = np.empty((len(states), size + 2 * BORDER, size + 2 * BORDER, 3), dtype=np.uint8)
    out[:] = colour
    for i, state in enumerate(states):
        env.set_state(state)
        out[i, BORDER:-BORDER, BORDER:-BORDER] = env.observe()[f"obs.image_{CAMERA}"]
    return out


def _grid(tiles: list[np.ndarray]) -> np.ndarray:
    n = len(tiles)
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    length = max(len(t) for t in tiles)
    h, w = tiles[0].shape[1:3]
    frames = np.zeros((length, rows * h, cols * w, 3), dtype=np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, cols)
        padded = np.concatenate([tile, np.repeat(tile[-1:], length - len(tile), axis=0)])
        frames[:, r * h : (r + 1) * h, c * w : (c + 1) * w] = padded
    return frames


def _write(path: Path, frames: np.ndarray, fps: float) -> None:
    import imageio.v3 as iio  # deferred: undeclared dependency (viser's), only for --video

    def gif(tmp: Path) -> None:
        # Pillow directly: imageio's GIF writer retries a failed write when it is garbage-collected (a traceback)
        from PIL import Image  # deferred: only for --video

        images = [Image.fromarray(f) for f in frames]
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=1000.0 / fps, loop=0)

    try:  # staged and renamed: a full disk leaves no truncated video (and names this file)
        replace_atomically(path, gif if path.suffix.lower() == ".gif" else
                           lambda tmp: iio.imwrite(tmp, frames, extension=".mp4", fps=fps))
    except (ImportError, OSError, ValueError, RuntimeError) as exc:
        hint = " (MP4 needs imageio-ffmpeg or av installed; use a .gif path)" if path.suffix.lower() == ".mp4" else ""
        raise DemoError(path, f"cannot write the video: {str(exc).splitlines()[0][:160]}{hint}") from None
