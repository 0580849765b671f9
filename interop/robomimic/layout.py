"""What a robomimic HDF5 file written by demo holds, and the names shared by the export and the import.

File layout written by :func:`~demo.interop.robomimic.export_robomimic` (and read by
:func:`~demo.interop.robomimic.import_robomimic`)::

    data                 attrs: total (frames), env_args (JSON), demo_meta (JSON, written by demo)
    data/demo_<i>        attrs: num_samples; episode.<column> for every per-episode column
      actions            [T, d] float32 (the store's action, in its representation)
      obs/<name>         obs.<name>, dtype kept (camera images uint8 [T, H, W, C], gzip)
      next_obs/<name>    obs shifted by one frame, the last frame repeated (robomimic's convention)
      states             sim.state [T, n] float64: MuJoCo mjSTATE_INTEGRATION (not robosuite's layout)
      rewards            [T] float64, sparse: 1.0 on the last frame of a successful episode
      dones              [T] int64: 1 on the last frame
      extra/<key>        every other store key (info.*, sim.* besides sim.state), ignored by robomimic
    mask/<name>          names (bytes) of the demos in store mask ``mask.<name>`` (robomimic filter keys)

``env_args`` is ``{"env_name": <task>, "type": "demo", "env_kwargs": {robot, task, control_freq}}``:
robomimic can train from the file, but cannot create the environment for rollouts (its env types
are robosuite/gym). ``demo_meta`` holds the store's metadata (fps, action representation name,
units and params, feature descriptions, robot, task, provenance), the key map and the arrow types of
the per-episode columns, which make store -> robomimic -> store bit-exact. Synthesised datasets
(``rewards``, ``dones``, ``next_obs``) are skipped when reading a file demo wrote.
"""

from __future__ import annotations

import re
from typing import Any

META_ATTR = "demo_meta"
COLUMN_ATTR = "episode."
DEMO_NAME = re.compile(r"demo_(\d+)")
DEFAULT_FPS = 20.0  # robomimic's robosuite datasets are recorded at 20 Hz control


def h5py_module() -> Any:
    """h5py, imported when a file is first read or written (not with :mod:`demo.interop`)."""
    import h5py  # deferred: h5py only when a robomimic file is read or written

    return h5py
