"""Training curves and success-vs-horizon figures: PNGs written, every method's points visible."""

from __future__ import annotations

from typing import Any

import demo.training.plots as plots

PNG = b"\x89PNG\r\n\x1a\n"


def _keep_figure(monkeypatch) -> list[Any]:
    """Record each figure, drawn, as it is saved (the real save still runs)."""
    kept: list[Any] = []
    real = plots.save_figure

    def save(fig, path, *args, **kwargs):
        fig.canvas.draw()
        kept.append(fig)
        return real(fig, path, *args, **kwargs)

    monkeypatch.setattr(plots, "save_figure", save)
    return kept


def test_success_vs_horizon_keeps_the_legend_off_the_data_and_names_the_options(tmp_path, monkeypatch) -> None:
    kept = _keep_figure(monkeypatch)
    lines = {f"method {i}": [{"horizon": h, "success_rate": 0.1 * i, "ci95": [0.05 * i, 0.15 * i]}
                             for h in (160, 260, 360, 460)] for i in range(9)}
    path = plots.plot_success_vs(lines, tmp_path / "c.png", top_ticks={160: "repeat=1", 460: "repeat=4"})
    assert path.read_bytes()[:8] == PNG
    ax = kept[0].axes[0]
    legend = ax.get_legend()
    assert len(legend.get_texts()) == 9
    assert legend.get_window_extent().x0 >= ax.get_window_extent().x1, "the legend must sit beside the axes"
    assert [t.get_text() for t in ax.child_axes[0].get_xticklabels()] == ["repeat=1", "repeat=4"]


def test_training_figure_draws_losses_evals_and_rounds(tmp_path) -> None:
    metrics = {"train_loss": [[0, 1.0], [100, 0.1]], "val_loss": [[0, 1.2], [100, 0.2]],
               "eval": [{"step": 100, "success_rate": 0.5, "ci95": [0.3, 0.7], "episodes": 10}],
               "rounds": [{"step": 50, "round": 1}]}
    assert plots.plot_training(metrics, tmp_path / "t.png", title="run").read_bytes()[:8] == PNG
