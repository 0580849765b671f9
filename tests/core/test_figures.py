"""Figures are staged and renamed: a failed write names the file and leaves the previous one."""

from __future__ import annotations

from pathlib import Path

import pytest

from demo.errors import DemoError
from demo.figures import pyplot, save_figure


def test_a_figure_replaces_the_previous_one_whole_or_not_at_all(tmp_path: Path) -> None:
    plt = pyplot()
    path = save_figure(plt.figure(), tmp_path / "curves.png")
    before = path.read_bytes()
    assert before.startswith(b"\x89PNG")
    fig = plt.figure()
    fig.savefig = lambda *a, **k: (_ for _ in ()).throw(OSError(28, "No space left on device"))  # a full disk
    with pytest.raises(DemoError, match="curves.png: could not be written \\(No space left on device\\)"):
        save_figure(fig, path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["curves.png"]
