"""The episode store shared by every stage: zarr arrays + a parquet episode table + metadata."""

from demo.store.episode_store import EpisodeStore
from demo.store.spec import ActionSpec, FeatureSpec, StoreMeta
from demo.store.windows import Batch, WindowSampler

__all__ = ["EpisodeStore", "ActionSpec", "FeatureSpec", "StoreMeta", "Batch", "WindowSampler"]
