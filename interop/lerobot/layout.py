"""What a LeRobotDataset v3.0 folder holds and where each store key goes: the layout's paths and
constants, and :class:`Column`, one store key's place in the dataset (shared by the export and the
import).

Layout written by :func:`~demo.interop.lerobot.export_lerobot` (and read by
:func:`~demo.interop.lerobot.import_lerobot`)::

    DIR/
      meta/info.json                             codebase_version "v3.0", fps, features, totals, paths
      meta/stats.json                            per feature: min max mean std count q01 q10 q50 q90 q99
      meta/tasks.parquet                         task (index) -> task_index
      meta/episodes/chunk-000/file-000.parquet   one row per episode (see below)
      data/chunk-000/file-000.parquet            one row per frame; a new file every ~100 MB
      videos/<camera feature>/chunk-000/file-000.mp4   the camera's frames, episodes one after another;
                                                 a new file every ~500 MB

How store keys become LeRobot features:

=====================  ==========================================================================
store                  LeRobot
=====================  ==========================================================================
``action``             ``action`` float32 [d], names = the action spec's names
float32 ``obs.*``      concatenated, in feature order, into ``observation.state`` float32; the
                       split is recorded in the feature's ``names`` (``joint_pos.j1``, ...)
uint8 [H,W,3] ``obs``  ``observation.images.<camera>``, ``dtype: video`` (the default): MP4 files in
                       LeRobot's ``videos/`` layout, AV1 ``yuv420p`` as LeRobot encodes them
                       (:mod:`demo.interop.video`; lossy: the export decodes what it wrote and
                       reports the pixel error); with ``images="embed"``, and for 1- or 4-channel
                       or tiny cameras, ``dtype: image``: PNG bytes embedded in the data parquet
                       (lossless)
other ``obs.*``,       extra columns named like the store key, dtype kept (``sim.state`` float64,
``sim.*``, ``info.*``  a float64/int/bool ``obs.*``): LeRobot reads every ``observation*`` feature
                       as a policy input, so only float32 obs go under ``observation.``
(structure)            ``timestamp`` float32 = frame_index / fps, ``frame_index``,
                       ``episode_index``, ``index``, ``task_index`` int64, ``next.done`` bool
=====================  ==========================================================================

Features of more than one dimension that are not images are flattened (LeRobot reads 1-D
sequences), their shape kept in the extras. Everything LeRobot has no place for (the store's
metadata: action representation name, params and units, robot, task options, provenance; the
exact key split) goes into ``meta/info.json`` under the ``"demo"`` key, which LeRobot ignores;
per-episode columns (success, seed, source, operator, masks, scores, ...) go into the episodes
parquet as ``demo/<column>`` with their arrow types. Together they make store -> LeRobot -> store
bit-exact. Episodes parquet columns: ``episode_index``, ``tasks``, ``length``,
``data/chunk_index``, ``data/file_index``, ``dataset_from_index``, ``dataset_to_index``,
``meta/episodes/chunk_index``, ``meta/episodes/file_index``, ``stats/<feature>/<stat>``,
``demo/<column>``, and per video feature ``videos/<feature>/chunk_index``, ``file_index``,
``from_timestamp``, ``to_timestamp`` (seconds into its file: frame ``k`` of the episode is presented
at ``from_timestamp + k / fps``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_FILE_MB = 100
VIDEO_FILE_MB = 500
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EXTRA_KEY = "demo"
EPISODE_COLUMN_PREFIX = "demo/"
STATE = "observation.state"
FRAME_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
DONE = "next.done"
# Per-frame outcome columns LeRobot's own tools keep (and its pusht/aloha datasets carry): True / 1.0 on the
# last frame of a successful episode. An import whose "demo" block was dropped reads success from them.
SUCCESS, REWARD = "next.success", "next.reward"
IMAGE_NAMES = ["height", "width", "channels"]
IMAGE_MODES = ("video", "embed")  # how camera features are exported: MP4 videos or PNG in the parquet


@dataclass(frozen=True)
class Column:
    """Where one store key lives in the LeRobot dataset."""

    key: str  # store key
    feature: str  # LeRobot feature name
    kind: str  # "state": a slice of observation.state | "image" (PNG in parquet) | "video" (MP4) | "array"
    shape: tuple[int, ...]  # store frame shape
    dtype: str
    start: int = 0  # slice of observation.state (kind "state")
    stop: int = 0

    @property
    def width(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) if self.shape else 1

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["shape"] = list(self.shape)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "Column":
        return cls(
            key=str(d["key"]), feature=str(d["feature"]), kind=str(d["kind"]),
            shape=tuple(int(s) for s in d["shape"]), dtype=str(d["dtype"]),
            start=int(d.get("start", 0)), stop=int(d.get("stop", 0)),
        )


def json_number(fps: float) -> int | float:
    """``fps`` as info.json writes it: an integer where it is one (``30``, not ``30.0``)."""
    return int(fps) if fps.is_integer() else fps
