"""JSON results: plain JSON of numpy values, atomic replacement of regular files only."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from demo.jsonio import write_json


def test_regular_files_are_replaced_and_fifos_written_in_place(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    write_json(target, {"x": np.float32(1.5), "nan": float("nan")})
    assert json.loads(target.read_text()) == {"x": 1.5, "nan": None}
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        write_json(fifo, {"ok": True})
        assert json.loads(os.read(reader, 1000)) == {"ok": True}
    finally:
        os.close(reader)
    assert not fifo.is_file()  # still a FIFO, not replaced by a regular file
