"""LeRobotDataset v3.0 (lerobot >= 0.4.0) export and import.

    from demo.interop.lerobot import export_lerobot, import_lerobot

Where each part lives:

- :mod:`~demo.interop.lerobot.layout`: the folder layout, how store keys become LeRobot features
  (the table in its docstring) and :class:`~demo.interop.lerobot.layout.Column`;
- :mod:`~demo.interop.lerobot.export`: store -> LeRobot folder (:func:`export_lerobot`);
- :mod:`~demo.interop.lerobot.import_`: LeRobot folder -> store (:func:`import_lerobot`);
- :mod:`~demo.interop.lerobot.files`: reading and checking the folder's JSON and parquet files
  (untrusted input), :func:`read_info`;
- :mod:`~demo.interop.lerobot.videos`: the camera features' MP4 files (``videos/``);
- :mod:`~demo.interop.lerobot.stats`: ``meta/stats.json`` and the episodes' ``stats/*`` columns.
"""

from demo.interop.lerobot.export import export_lerobot, plan_columns
from demo.interop.lerobot.files import read_info
from demo.interop.lerobot.import_ import import_lerobot

__all__ = ["export_lerobot", "import_lerobot", "plan_columns", "read_info"]
