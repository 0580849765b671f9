"""MP4 video for camera features: encode uint8 RGB frames, decode them back, measure the pixel error.

Both directions use PyAV, whose wheels bundle FFmpeg (nothing to install on the system). The
default encoding is LeRobot's: AV1 by SVT-AV1 (``libsvtav1``), ``yuv420p``, CRF 30, a keyframe
every 2 frames; PyAV's FFmpeg decodes AV1 with libdav1d. AV1 in ``yuv420p`` is lossy (colour is
kept at half resolution), so a round trip changes pixels: :class:`PixelError` says by how much,
in 0-255 units.

Timestamps are exact: frame ``k`` of a clip is encoded with pts ``k`` in the time base ``1/fps``,
so it is presented at ``k / fps`` seconds; :class:`ClipWriter` puts clips one after another in a
file, shifting each by the frames before it. A reader asks for frames by time (LeRobot's
``from_timestamp + frame_index / fps``) and accepts a frame within :data:`TOLERANCE_S` of it, the
tolerance LeRobot's own decoder checks.

Videos are untrusted input: every failure to open or decode one, a frame size other than the one
declared, or fewer frames than asked for is a :class:`~demo.errors.DemoError` naming the file.
"""

from __future__ import annotations

import io
import os
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import av
import numpy as np

from demo.errors import DemoError, first_line

CODEC = "libsvtav1"  # FFmpeg's encoder name
PIX_FMT = "yuv420p"
CRF = 30
GOP = 2  # frames between keyframes: cheap random access for a data loader, as LeRobot sets it
MIN_SIDE = 4  # SVT-AV1 refuses frames narrower or lower than 4 pixels (in the FFmpeg of PyAV 18.1.0; 18.1.1 pads them)
TOLERANCE_S = 1e-4  # seconds between a requested timestamp and the frame that answers it (LeRobot's)
RATE_DENOMINATOR = 1001  # frame rates are written as fractions: 30000/1001 for NTSC's 29.97


@dataclass(frozen=True)
class VideoSettings:
    """How camera frames are encoded (FFmpeg's names and options)."""

    codec: str = CODEC
    pix_fmt: str = PIX_FMT
    crf: int = CRF  # constant rate factor: lower is closer to the source and larger
    gop: int = GOP

    def options(self) -> dict[str, str]:
        return {"g": str(self.gop), "crf": str(self.crf)}


def rate(fps: float) -> Fraction:
    """A frame rate (frames/s) as the fraction a container and encoder need."""
    return Fraction(fps).limit_denominator(RATE_DENOMINATOR)


def unencodable(shape: tuple[int, ...]) -> str | None:
    """Why uint8 frames of ``shape`` ``[H, W, C]`` cannot become a video here, or None if they can."""
    if len(shape) != 3 or shape[2] != 3:
        return f"frames of shape {list(shape)} are not RGB (video carries 3 channels)"
    if min(shape[:2]) < MIN_SIDE:
        return f"frames of {shape[1]}x{shape[0]} pixels are below the encoder's {MIN_SIDE}x{MIN_SIDE} minimum"
    return None


def _problem(exc: BaseException) -> str:
    """FFmpeg's words for a failure, without PyAV's ``[Errno N]`` prefix, on one line."""
    strerror = getattr(exc, "strerror", None)
    return first_line(ValueError(strerror)) if strerror else first_line(exc)


# ---------------------------------------------------------------------------------------------- encode
def encode_clip(frames: np.ndarray, fps: float, settings: VideoSettings = VideoSettings(),
                where: str | Path = "video") -> bytes:
    """``frames`` (uint8 ``[T, H, W, 3]``) as the bytes of one MP4 file, frame ``k`` at ``k / fps`` s.

    ``where`` names the video in errors."""
    if frames.ndim != 4 or frames.shape[3] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames {frames.dtype} {list(frames.shape)}, expected uint8 [T, H, W, 3]")
    # SVT-AV1 prints its configuration to stderr for every encoder unless told otherwise; a
    # command's stderr holds progress bars and one-line errors only. A user's SVT_LOG wins.
    os.environ.setdefault("SVT_LOG", "1")
    buffer = io.BytesIO()
    time_base = Fraction(1) / rate(fps)
    with av.open(buffer, "w", format="mp4") as container:
        try:
            stream = container.add_stream(settings.codec, rate=rate(fps), options=settings.options())
            stream.height, stream.width = frames.shape[1:3]
            stream.pix_fmt = settings.pix_fmt
            for k, image in enumerate(frames):
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
                frame.pts, frame.time_base = k, time_base
                container.mux(stream.encode(frame))
            container.mux(stream.encode(None))  # the frames the encoder held back
        except Exception as exc:  # PyAV raises many types for an unknown codec, option or size
            raise DemoError(where, f"cannot encode {settings.codec} video ({_problem(exc)})") from None
    return buffer.getvalue()


def write_video(path: str | Path, frames: np.ndarray, fps: float, settings: VideoSettings = VideoSettings()) -> None:
    """Write ``frames`` (uint8 ``[T, H, W, 3]``) as one MP4 file at ``fps`` frames/s."""
    Path(path).write_bytes(encode_clip(frames, fps, settings, path))


class ClipWriter:
    """One MP4 file made of whole clips (:func:`encode_clip`) one after another, without re-encoding
    (as LeRobot concatenates episodes): a clip's frame ``k`` is presented at ``(n + k) / fps`` s,
    ``n`` being the frames of the clips before it. Sizes are exact, so where a caller starts a new
    file does not depend on an encoder's timing."""

    def __init__(self, path: str | Path, fps: float):
        self.path = Path(path)
        self.rate = rate(fps)
        self.frames = 0
        self.bytes = 0  # compressed bytes of the clips appended
        self._container = av.open(str(self.path), "w", format="mp4")
        self._stream: Any = None

    def append(self, clip: bytes, frames: int) -> None:
        """Append an MP4 clip of ``frames`` frames after those already in the file."""
        offset = Fraction(self.frames) / self.rate  # seconds
        try:
            with av.open(io.BytesIO(clip), "r") as source:
                video = source.streams.video[0]
                if self._stream is None:
                    self._stream = self._container.add_stream_from_template(video, opaque=True)
                for packet in source.demux(video):
                    if packet.dts is None:  # the demuxer's end-of-stream marker
                        continue
                    shift = round(offset / packet.time_base)
                    packet.pts, packet.dts = packet.pts + shift, packet.dts + shift
                    packet.stream = self._stream
                    self.bytes += packet.size
                    self._container.mux(packet)
        except av.error.FFmpegError as exc:
            raise DemoError(self.path, f"cannot append a clip ({_problem(exc)})") from None
        self.frames += frames

    def close(self) -> None:
        self._container.close()

    def abandon(self) -> None:
        """Close the file without caring whether it is whole (the caller removes it after a failure)."""
        try:
            self._container.close()
        except av.error.FFmpegError:
            pass  # a half-written file is being thrown away; the failure that got here is the one to report


# ---------------------------------------------------------------------------------------------- decode
@dataclass(frozen=True)
class StreamInfo:
    """What a video file says about its first video stream."""

    codec: str  # FFmpeg's codec name, e.g. "av1"
    pix_fmt: str | None
    height: int
    width: int


class VideoDecoder:
    """Reads frames of one MP4 file by timestamp, moving forward through the file.

    ``shape``: the frame size ``[H, W, 3]`` the dataset declares; a stream of another size is
    refused before any frame is decoded. Asking for an earlier time than the last frame read seeks
    back (to the keyframe before it).
    """

    def __init__(self, path: str | Path, shape: tuple[int, ...]):
        self.path = Path(path)
        self.shape = tuple(shape)
        try:
            self._container = av.open(str(self.path), "r")
        except Exception as exc:  # PyAV raises many types for an unreadable file
            raise DemoError(self.path, f"is not a readable video ({_problem(exc)})") from None
        try:
            if not self._container.streams.video:
                raise DemoError(self.path, "holds no video stream")
            self._stream = self._container.streams.video[0]
            context = self._stream.codec_context
            self.info = StreamInfo(context.codec.canonical_name, context.format.name if context.format else None,
                                   context.height, context.width)
            if (context.height, context.width) != self.shape[:2]:
                raise DemoError(self.path, f"frames are {context.width}x{context.height} pixels, the feature declares "
                                           f"{self.shape[1]}x{self.shape[0]}")
        except BaseException:
            self._container.close()
            raise
        self._frames: Iterator[av.VideoFrame] | None = None
        self._last = -np.inf  # time (s) of the last frame taken from the decoder

    def _decoded(self) -> Iterator[av.VideoFrame]:
        try:
            yield from self._container.decode(self._stream)
        except av.error.FFmpegError as exc:
            where = "at its start" if self._last == -np.inf else f"after the frame at {self._last:.4f} s"
            raise DemoError(self.path, f"is corrupted: decoding failed {where} ({_problem(exc)})") from None

    def _seek(self, time_s: float) -> None:
        base = self._stream.time_base
        try:
            self._container.seek(max(int(time_s / base), 0) if base else 0, stream=self._stream, backward=True)
        except av.error.FFmpegError as exc:
            raise DemoError(self.path, f"cannot seek to {time_s:.4f} s ({_problem(exc)})") from None
        self._frames, self._last = None, -np.inf

    def read(self, start_s: float, count: int, fps: float) -> np.ndarray:
        """``count`` frames presented at ``start_s + j / fps`` s (j = 0..count-1), uint8 ``[count, H, W, 3]``."""
        if start_s <= self._last + TOLERANCE_S:
            self._seek(start_s)
        if self._frames is None:
            self._frames = self._decoded()
        wanted = start_s + np.arange(count) / fps
        out = np.empty((count, *self.shape[:2], 3), dtype=np.uint8)
        j = 0
        while j < count:
            frame = next(self._frames, None)
            if frame is None:
                raise DemoError(self.path, f"ends after {j} of the {count} frames from {start_s:.4f} s "
                                           "(fewer frames than the episode length)")
            if frame.pts is None or frame.time_base is None:
                raise DemoError(self.path, "has a frame without a timestamp")
            time = float(frame.pts * frame.time_base)
            self._last = time
            if time < wanted[j] - TOLERANCE_S:  # before the frames asked for (an earlier episode)
                continue
            if time > wanted[j] + TOLERANCE_S:
                raise DemoError(self.path, f"has no frame at {wanted[j]:.4f} s (frame {j} of the {count} from "
                                           f"{start_s:.4f} s); the next one is at {time:.4f} s")
            if (frame.height, frame.width) != self.shape[:2]:
                raise DemoError(self.path, f"frame at {time:.4f} s is {frame.width}x{frame.height} pixels, the "
                                           f"feature declares {self.shape[1]}x{self.shape[0]}")
            try:
                out[j] = frame.to_ndarray(format="rgb24")
            except Exception as exc:  # PyAV raises many types for a frame it cannot convert
                raise DemoError(self.path, f"frame at {time:.4f} s cannot be converted to RGB ({_problem(exc)})") from None
            j += 1
        return out

    def close(self) -> None:
        self._container.close()

    def __enter__(self) -> "VideoDecoder":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def read_video(path: str | Path, shape: tuple[int, ...], count: int, fps: float, start_s: float = 0.0) -> np.ndarray:
    """``count`` frames of the MP4 at ``path`` from ``start_s`` s, uint8 ``[count, H, W, 3]``."""
    with VideoDecoder(path, shape) as decoder:
        return decoder.read(start_s, count, fps)


# ---------------------------------------------------------------------------------------------- error
@dataclass
class PixelError:
    """Absolute difference between source and decoded frames, in 0-255 units, accumulated over
    frames; ``crc32`` fingerprints the decoded frames in the order they were added, so a later
    decode can tell whether it got the very same pixels."""

    frames: int = 0
    values: int = 0  # pixel channel values compared
    abs_sum: int = 0
    max_abs: int = 0
    crc32: int = 0

    def add(self, source: np.ndarray, decoded: np.ndarray) -> None:
        """Compare uint8 ``source`` and ``decoded`` frames ``[T, H, W, C]`` of the same shape."""
        if source.shape != decoded.shape:
            raise ValueError(f"source {source.shape} and decoded {decoded.shape} frames differ in shape")
        diff = np.abs(source.astype(np.int16) - decoded.astype(np.int16))
        self.values += int(diff.size)
        self.abs_sum += int(diff.sum(dtype=np.int64))
        self.max_abs = max(self.max_abs, int(diff.max(initial=0)))
        self.fingerprint(decoded)

    def fingerprint(self, decoded: np.ndarray) -> None:
        """Count ``decoded`` frames and fold them into :attr:`crc32` (with or without a source)."""
        self.frames += len(decoded)
        self.crc32 = zlib.crc32(np.ascontiguousarray(decoded).data, self.crc32)

    @property
    def mean_abs(self) -> float:
        return self.abs_sum / self.values if self.values else 0.0
