"""demo.interop: export/import between stores and other stacks' formats, lossless but for camera videos.

    from demo.interop import export_lerobot, import_lerobot, export_robomimic, import_robomimic
    report = export_lerobot("pick.zarr", "pick_lerobot")      # LeRobotDataset v3.0 folder
    report = import_robomimic("lift.hdf5", "lift.zarr")       # robomimic HDF5 -> store

Each returns an :class:`~demo.interop.common.InteropReport` (what was written, what is kept only in
demo-specific metadata, what the format could not carry). LeRobot cameras go to MP4 videos by
default (:mod:`demo.interop.video`; ``images="embed"`` keeps PNGs): lossy, so the report carries each
camera's measured round-trip pixel error.
"""

from demo.interop.common import InteropReport
from demo.interop.lerobot import export_lerobot, import_lerobot
from demo.interop.robomimic import export_robomimic, import_robomimic

__all__ = ["InteropReport", "export_lerobot", "import_lerobot", "export_robomimic", "import_robomimic"]
