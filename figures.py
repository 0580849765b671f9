"""Matplotlib for PNG files: the headless backend and one way to save a figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from demo.errors import DemoError, first_line
from demo.jsonio import replace_atomically


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (no display needed); imported on first use."""
    import matplotlib  # deferred: heavy dependency (matplotlib), only where a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: after choosing the Agg backend

    return plt


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` (parent folders made; staged and renamed, so a full disk leaves the previous
    figure, and names this file), close it and return the path."""
    path = Path(path)
    try:
        replace_atomically(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png"))
    except OSError as exc:
        raise DemoError(path, f"could not be written ({exc.strerror or first_line(exc)})") from None
    finally:
        pyplot().close(fig)
    return path


def success_lines(series: dict[str, list[tuple[float, float, float, float]]], path: str | Path, xlabel: str,
                  title: str, xticks: list[float] | None = None) -> Path:
    """Success (%) against a swept setting, one line per series with its 95% interval as a band: each point
    ``(x, success rate, interval low, interval high)``, rates as fractions."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    for label, points in series.items():
        points = sorted(points)
        xs = [p[0] for p in points]
        line, = ax.plot(xs, [100 * p[1] for p in points], marker="o", label=label)
        ax.fill_between(xs, [100 * p[2] for p in points], [100 * p[3] for p in points], color=line.get_color(),
                        alpha=0.12)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("success (%)")
    if xticks is not None:
        ax.set_xticks(xticks)
    ax.set_ylim(0, 102)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)
