"""Whether reads check what they read: on by default, off for a user who knows (``demo --no-verify``).

Store reads check that every chunk file they read from exists (zarr would read a missing one as zeros)
and that a whole episode matches its CRC-32 (:mod:`demo.store.reading`), so damage is refused where it
is read and not passed on under a fresh checksum. ``demo --no-verify`` turns both off for the command
and its worker processes, through the environment (they inherit it); ``demo info --check`` verifies
regardless. Kept apart from the store so that the command line can set it without importing zarr.
"""

from __future__ import annotations

import os

NO_VERIFY_ENV = "DEMO_NO_VERIFY"  # set to anything but "" or "0": reads do not check


def verifying() -> bool:
    """Whether reads check what they read (module docstring)."""
    return os.environ.get(NO_VERIFY_ENV, "0") in ("", "0")
