"""PNG plots of training runs and experiments (matplotlib, Agg backend, no display needed)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from demo.figures import pyplot, save_figure


def plot_training(metrics: Mapping[str, Any], path: str | Path, title: str = "") -> Path:
    """Loss (train, validation; log scale) and rollout success (with 95% interval) against step.

    ``metrics``: ``train_loss`` / ``val_loss`` as ``[[step, value], ...]``, ``eval`` as
    ``[{"step", "success_rate", "ci95"}, ...]`` and optionally ``rounds`` (DAgger round boundaries,
    ``[{"step", "round"}, ...]``) drawn as vertical lines.
    """
    plt = pyplot()
    evals = list(metrics.get("eval") or [])
    fig, axes = plt.subplots(1, 2 if evals else 1, figsize=(10 if evals else 5.5, 3.8), squeeze=False)
    ax = axes[0, 0]
    for key, label in (("train_loss", "train"), ("val_loss", "validation")):
        pts = np.asarray(metrics.get(key) or [], dtype=float).reshape(-1, 2)
        if len(pts):
            ax.plot(pts[:, 0], pts[:, 1], label=label, lw=1.4)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss (normalised actions)")
    ax.grid(alpha=0.3)
    ax.legend()
    rounds = list(metrics.get("rounds") or [])
    if evals:
        ax2 = axes[0, 1]
        steps = np.array([e["step"] for e in evals], dtype=float)
        rate = np.array([e["success_rate"] for e in evals], dtype=float)
        lo = np.array([e["ci95"][0] for e in evals], dtype=float)
        hi = np.array([e["ci95"][1] for e in evals], dtype=float)
        ax2.fill_between(steps, lo, hi, alpha=0.2)
        ax2.plot(steps, rate, "o-", lw=1.4)
        ax2.set_ylim(-0.02, 1.02)
        ax2.set_xlabel("step")
        ax2.set_ylabel(f"rollout success ({evals[-1].get('episodes', '?')} episodes)")
        ax2.grid(alpha=0.3)
    for r in rounds:
        for a in axes[0]:
            a.axvline(r["step"], color="grey", lw=0.8, ls=":")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_success_vs(
    lines: Mapping[str, Sequence[Mapping[str, Any]]],
    path: str | Path,
    x_key: str = "horizon",
    x_label: str = "task horizon (control steps)",
    title: str = "",
    top_ticks: Mapping[float, str] | None = None,
) -> Path:
    """Success rate (with 95% interval bars) against ``x_key`` for several methods.

    ``lines``: method -> ``[{x_key, "success_rate", "ci95"}, ...]``; ``top_ticks`` (x -> label) names
    the x values once, on a top axis (e.g. the task option that sets the horizon).
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.4, 4.2))
    for name, points in lines.items():
        pts = sorted(points, key=lambda p: p[x_key])
        if not pts:
            continue
        x = np.array([p[x_key] for p in pts], dtype=float)
        y = np.array([p["success_rate"] for p in pts], dtype=float)
        err = np.clip(np.array([[y[i] - p["ci95"][0], p["ci95"][1] - y[i]] for i, p in enumerate(pts)]).T, 0, None)
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3, lw=1.6, label=name)
    ax.set_ylim(-0.02, 1.05)
    if top_ticks:
        top = ax.secondary_xaxis("top")
        top.set_xticks(list(top_ticks), labels=list(top_ticks.values()))
    ax.set_xlabel(x_label)
    ax.set_ylabel("success rate (95% Wilson interval)")
    ax.grid(alpha=0.3)
    # Outside the axes: with many methods any corner inside covers someone's points.
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return save_figure(fig, path)
