"""The camera features' MP4 files in LeRobot's ``videos/`` layout: :class:`VideoWriter` encodes each
episode and appends it to the current file of its feature (export), :class:`VideoReader` decodes an
episode's frames from the file and time ``meta/episodes`` points at (import). Frames are uint8
``[T, H, W, 3]``; times are seconds into a file (frame ``k`` of an episode at ``from_timestamp + k / fps``).
The encoding itself (AV1 ``yuv420p``, PyAV) is :mod:`demo.interop.video`'s.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.interop.common import VideoReport
from demo.interop.lerobot.layout import CHUNKS_SIZE, INFO_PATH, VIDEO_PATH, Column, json_number
from demo.interop.untrusted import MAX_EPISODE_FRAMES, contained
from demo.interop.video import ClipWriter, PixelError, StreamInfo, VideoDecoder, VideoSettings, encode_clip


def video_info(shape: tuple[int, ...], fps: float, settings: VideoSettings) -> dict[str, Any]:
    """A video feature's ``info`` block, as LeRobot describes the files it encodes."""
    return {
        "video.height": shape[0],
        "video.width": shape[1],
        "video.codec": "av1" if settings.codec == "libsvtav1" else settings.codec,
        "video.pix_fmt": settings.pix_fmt,
        "video.is_depth_map": False,
        "video.fps": json_number(fps),
        "video.channels": shape[2],
        "has_audio": False,
    }


class VideoWriter:
    """One camera feature's ``videos/<feature>/chunk-CCC/file-FFF.mp4`` files: each episode is
    encoded on its own and appended to the current file (as LeRobot concatenates them); an episode
    that would bring a file to ``file_mb`` starts the next one.

    Each finished file is decoded again and compared with the source frames (``reference(episode)``,
    read from the store anew rather than kept in memory), giving the exact round-trip error."""

    def __init__(self, root: Path, column: Column, fps: float, settings: VideoSettings, file_mb: float,
                 reference: Callable[[int], np.ndarray]):
        self.root, self.column, self.fps, self.settings = root, column, fps, settings
        self.limit = file_mb * 2**20
        self.reference = reference
        self.file_number = 0
        self.writer: ClipWriter | None = None
        self.in_file: list[tuple[int, int, int]] = []  # (source episode, first frame in the file, length)
        self.files: list[str] = []
        self.error = PixelError()

    def _path(self, file_number: int) -> str:
        chunk, file = divmod(file_number, CHUNKS_SIZE)
        return VIDEO_PATH.format(video_key=self.column.feature, chunk_index=chunk, file_index=file)

    def add(self, source_episode: int, frames: np.ndarray) -> dict[str, Any]:
        """Encode one episode's frames; return its ``videos/<feature>/*`` episode columns."""
        clip = encode_clip(frames, self.fps, self.settings, self.root / self._path(self.file_number))
        if self.writer is not None and self.writer.bytes + len(clip) >= self.limit:
            self.flush()
        if self.writer is None:
            path = self.root / self._path(self.file_number)
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = ClipWriter(path, self.fps)
        start = self.writer.frames
        self.writer.append(clip, len(frames))
        self.in_file.append((source_episode, start, len(frames)))
        chunk, file = divmod(self.file_number, CHUNKS_SIZE)
        prefix = f"videos/{self.column.feature}/"
        return {prefix + "chunk_index": chunk, prefix + "file_index": file,
                prefix + "from_timestamp": start / self.fps, prefix + "to_timestamp": (start + len(frames)) / self.fps}

    def flush(self) -> None:
        """Finish the current file and measure it against the source frames."""
        if self.writer is None:
            return
        self.writer.close()
        with VideoDecoder(self.writer.path, self.column.shape) as decoder:
            for episode, start, length in self.in_file:
                self.error.add(self.reference(episode), decoder.read(start / self.fps, length, self.fps))
        self.files.append(self._path(self.file_number))
        self.writer, self.in_file = None, []
        self.file_number += 1

    def abandon(self) -> None:
        """Close an unfinished file (the export failed; its folder is removed)."""
        if self.writer is not None:
            self.writer.abandon()
            self.writer = None

    def report(self) -> VideoReport:
        return VideoReport(self.column.key, self.column.feature, video_info(self.column.shape, self.fps, self.settings)
                           ["video.codec"], self.settings.pix_fmt, self.error.frames, len(self.files),
                           self.error.mean_abs, self.error.max_abs, "decoded the written files")

    def extras(self) -> dict[str, Any]:
        """What info.json's ``demo`` block records of this video (the import reports it)."""
        return {"codec": self.settings.codec, "pix_fmt": self.settings.pix_fmt, "crf": self.settings.crf,
                "gop": self.settings.gop, "frames": self.error.frames, "mean_abs_error": self.error.mean_abs,
                "max_abs_error": self.error.max_abs, "decoded_crc32": self.error.crc32}


class VideoReader:
    """Video features' frames, episode by episode, from the files ``meta/episodes`` points at
    (``video_path`` filled with its ``videos/<feature>/chunk_index`` and ``file_index``), starting
    at its ``from_timestamp``; one file open per feature at a time."""

    def __init__(self, root: Path, info: dict[str, Any], episodes_where: Path):
        self.root, self.info_path, self.where = root, root / INFO_PATH, episodes_where
        self.template: str | None = info.get("video_path")
        self.fps = float(info["fps"])
        self.open: dict[str, tuple[Path, VideoDecoder]] = {}
        self.decoded: dict[str, PixelError] = {}
        self.files: dict[str, set[Path]] = {}
        self.streams: dict[str, StreamInfo] = {}

    def frames(self, c: Column, episode: int, row: dict[str, Any], length: int) -> np.ndarray:
        """Episode ``episode``'s ``length`` frames of video feature ``c``, uint8 ``[length, H, W, 3]``."""
        if self.template is None:
            raise DemoError(self.info_path, f"feature {c.feature!r} is a video but video_path is null")
        prefix = f"videos/{c.feature}/"
        chunk, file, start = (row.get(prefix + k) for k in ("chunk_index", "file_index", "from_timestamp"))
        if chunk is None or file is None or start is None:
            raise DemoError(self.where, f"episode {episode} has no {prefix}chunk_index, file_index and from_timestamp")
        if isinstance(start, bool) or not isinstance(start, (int, float)) or not 0 <= start <= MAX_EPISODE_FRAMES / self.fps:
            raise DemoError(self.where, f"episode {episode}: {prefix}from_timestamp {start!r} is not a time in the video")
        rel = self.template.format(video_key=c.feature, chunk_index=chunk, file_index=file, episode_chunk=chunk,
                                   episode_index=episode)
        path = contained(self.root, rel, self.info_path, "video_path")
        current = self.open.get(c.feature)
        if current is None or current[0] != path:
            if current is not None:
                current[1].close()
                del self.open[c.feature]
            if not path.is_file():
                raise DemoError(path, "is missing")
            decoder = VideoDecoder(path, c.shape)
            self.open[c.feature] = (path, decoder)
            self.files.setdefault(c.feature, set()).add(path)
            self.streams[c.feature] = decoder.info
        frames = self.open[c.feature][1].read(float(start), length, self.fps)
        self.decoded.setdefault(c.feature, PixelError()).fingerprint(frames)
        return frames

    def close(self) -> None:
        for _, decoder in self.open.values():
            decoder.close()
        self.open.clear()

    def report(self, c: Column, extras: dict[str, Any] | None) -> VideoReport:
        """What was decoded for ``c``, with the round-trip error demo measured at export when the
        frames decoded here are the very ones it measured (same fingerprint)."""
        decoded = self.decoded.get(c.feature, PixelError())
        stream = self.streams.get(c.feature)
        recorded = _recorded_error(((extras or {}).get("videos") or {}).get(c.feature))
        mean: float | None = None
        peak: int | None = None
        measured = "no source frames to compare with (not exported by demo)"
        if recorded is not None:
            mean, peak, frames, crc = recorded
            if (frames, crc) == (decoded.frames, decoded.crc32):
                measured = "decoded frames identical to those demo measured against the source store at export"
            else:
                measured = "measured at export; the frames decoded here differ from those (another FFmpeg build?)"
        return VideoReport(c.key, c.feature, stream.codec if stream else "?", stream.pix_fmt if stream else None,
                           decoded.frames, len(self.files.get(c.feature, ())), mean, peak, measured)


def _recorded_error(value: Any) -> tuple[float, int, int, int] | None:
    """(mean, max, frames, crc32) from info.json's record of an export's video, if well formed."""
    if not isinstance(value, dict):
        return None
    fields = (value.get("mean_abs_error"), value.get("max_abs_error"), value.get("frames"), value.get("decoded_crc32"))
    if not isinstance(fields[0], (int, float)) or not all(isinstance(f, int) for f in fields[1:]):
        return None
    return float(fields[0]), int(fields[1]), int(fields[2]), int(fields[3])
