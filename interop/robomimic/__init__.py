"""robomimic HDF5 export and import (h5py).

    from demo.interop.robomimic import export_robomimic, import_robomimic

Where each part lives:

- :mod:`~demo.interop.robomimic.layout`: the file layout (its docstring) and the names both sides share;
- :mod:`~demo.interop.robomimic.export`: store -> robomimic file (:func:`export_robomimic`);
- :mod:`~demo.interop.robomimic.import_`: robomimic file -> store (:func:`import_robomimic`), with
  the checks that keep an untrusted file from reading outside itself.
"""

from demo.interop.robomimic.export import export_robomimic
from demo.interop.robomimic.import_ import import_robomimic

__all__ = ["export_robomimic", "import_robomimic"]
