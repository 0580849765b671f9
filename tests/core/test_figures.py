"""save_figure writes a PNG into folders it makes and closes the figure."""

from __future__ import annotations

from demo.figures import pyplot, save_figure


def test_save_figure_writes_png_and_closes(tmp_path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    path = save_figure(fig, tmp_path / "a" / "b.png", dpi=50)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert fig.number not in plt.get_fignums()
