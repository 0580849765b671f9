"""What curation did: per-episode decisions with reasons, per-operator keep rates, JSON and a PNG.

The per-operator rows say, for every operator (and for the failed episodes of any operator), how
many episodes were kept and how many dropped, and for which reasons.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from demo.curate.curate import ALL_SIGNALS, REASONS, Curation
from demo.figures import pyplot, save_figure

FAILED_ROW = "(failed, any operator)"


def _operators(table: Any) -> np.ndarray:
    ops = np.asarray(table.column("operator").to_pylist(), dtype=object)
    return np.array(["" if o is None else str(o) for o in ops], dtype=object)


def operator_rows(curation: Curation) -> list[dict[str, Any]]:
    """Per operator (and :data:`FAILED_ROW` for failures of any operator): counts and kept/dropped shares."""
    ops = _operators(curation.table)
    success = curation.signals["success"] > 0.5
    groups: list[tuple[str, np.ndarray]] = [(op or "(none)", ops == op) for op in sorted(set(ops.tolist()))]
    if (~success).any():
        groups.append((FAILED_ROW, ~success))
    rows = []
    for name, sel in groups:
        n = int(sel.sum())
        kept = int((curation.kept & sel).sum())
        reasons = Counter(code for i in np.flatnonzero(sel & ~curation.kept) for code in curation.codes[i])
        rows.append(
            {
                "operator": name,
                "episodes": n,
                "failed": int((sel & ~success).sum()),
                "kept": kept,
                "kept_share": kept / n if n else float("nan"),
                "dropped_share": (n - kept) / n if n else float("nan"),
                "dropped_for": {code: reasons[code] for code in REASONS if reasons[code]},
            }
        )
    return rows


def thresholds(curation: Curation) -> dict[str, Any]:
    c = curation.config
    return {
        "drop_failed": c.drop_failed,
        "trim_idle": c.trim_idle,
        "max_idle": c.max_idle,
        "idle_measure": "pause_fraction" if c.trim_idle else "idle_fraction",
        "max_jerk": c.max_jerk,
        "min_consistency": c.min_consistency,
        "consistency_spread_floor": float(curation.signals["spread_floor"][0]) if len(curation.kept) else None,
        "max_novelty": c.max_novelty,
        "max_length_z": c.max_length_z,
        "dedupe": c.dedupe,
        "dedupe_tol": c.duplicates.tol,
        "min_time_left_s": c.min_time_left_s,
        "min_margin": c.min_margin,
    }


def build(curation: Curation, *, source: str | Path, out: str | Path | None, mask: str | None) -> dict[str, Any]:
    """The JSON report: settings, signal docs, summary, per-operator table and every episode."""
    ops = _operators(curation.table)
    lengths = curation.lengths
    trim = curation.trim
    rows = operator_rows(curation)
    kept_frames = int((trim[:, 1] - trim[:, 0])[curation.kept].sum())
    episodes = []
    for i in range(len(lengths)):
        episodes.append(
            {
                "episode": i,
                "operator": ops[i],
                "success": bool(curation.signals["success"][i] > 0.5),
                "length": int(lengths[i]),
                "kept": bool(curation.kept[i]),
                "reasons": curation.reasons[i],
                "codes": curation.codes[i],
                "trim": [int(trim[i, 0]), int(trim[i, 1])] if curation.kept[i] and bool(curation.trimmed[i]) else None,
                "signals": {s.name: float(curation.signals[s.name][i]) for s in ALL_SIGNALS},
            }
        )
    return {
        "source": str(source),
        "out": None if out is None else str(out),
        "mask": mask,
        "thresholds": thresholds(curation),
        "config": curation.config.to_json(),
        "signals": {s.name: {"units": s.units, "description": s.description} for s in ALL_SIGNALS},
        "summary": {
            "episodes": int(len(lengths)),
            "kept": int(curation.kept.sum()),
            "dropped": int((~curation.kept).sum()),
            "trimmed": int(curation.trimmed.sum()),
            "frames_in": int(lengths.sum()),
            "frames_out": kept_frames,
            "dropped_by_reason": {code: sum(code in c for c in curation.codes) for code in REASONS},
        },
        "operators": rows,
        "timing_s": curation.timing,
        "episodes": episodes,
    }


def episode_table_rows(report: dict[str, Any], show: str, limit: int = 200) -> tuple[list[tuple], int]:
    """Rows for the terminal table (``show``: all / dropped / none) and how many were left out."""
    if show == "none":
        return [], 0
    chosen = [e for e in report["episodes"] if show == "all" or not e["kept"]]
    rows = []
    for e in chosen[:limit]:
        trim = f"{e['trim'][0]}:{e['trim'][1]}" if e["trim"] else ""
        rows.append(
            (
                e["episode"],
                e["operator"] or "-",
                "yes" if e["success"] else "no",
                e["length"],
                "[green]kept[/]" if e["kept"] else "[red]dropped[/]",
                trim,
                "; ".join(e["reasons"]),
            )
        )
    return rows, max(0, len(chosen) - limit)


# Signals drawn in the PNG, with the threshold(s) of the filter that reads them.
def _panels(curation: Curation) -> list[tuple[str, str, list[float], bool]]:
    c = curation.config
    idle_key = "pause_fraction" if c.trim_idle else "idle_fraction"
    return [
        ("jerk", "jerk [range/s^3]", [c.max_jerk] if c.max_jerk is not None else [], True),
        ("consistency", "consistency [fraction]", [c.min_consistency] if c.min_consistency is not None else [], False),
        (idle_key, f"{idle_key} [fraction]", [c.max_idle] if c.max_idle is not None else [], False),
        ("length_z", "length z [MAD units]", [c.max_length_z] if c.max_length_z is not None else [], False),
        ("idle_start_s", "idle start [s]", [c.idle.min_run_s] if c.trim_idle else [], False),
        ("disagreement", "disagreement [range units]", [], False),
        ("dup_distance", "nearest-episode distance [range units]", [c.duplicates.tol] if c.dedupe else [], True),
        ("time_left_s", "time left before horizon [s]", [c.min_time_left_s] if c.min_time_left_s is not None else [], False),
        ("novelty", "novelty [normalised obs units]", [c.max_novelty] if c.max_novelty is not None else [], False),
    ]


def plot(curation: Curation, path: str | Path) -> Path:
    """PNG of every signal's distribution (per operator when there are several, else kept vs
    dropped) with the filter thresholds as dashed lines."""
    plt = pyplot()
    ops = _operators(curation.table)
    names = sorted(set(ops.tolist()))
    if len(names) > 1:
        groups = [(name or "(none)", ops == name) for name in names]
    else:
        groups = [("kept", curation.kept), ("dropped", ~curation.kept)]
    panels = _panels(curation)
    cols = 3
    fig, axes = plt.subplots((len(panels) + cols - 1) // cols, cols, figsize=(5 * cols, 3.4 * ((len(panels) + cols - 1) // cols)))
    for ax, (key, label, lines, log) in zip(axes.flat, panels):
        values = np.asarray(curation.signals[key], dtype=np.float64)
        finite = np.isfinite(values)
        if log and (values[finite] > 0).any():
            # Zeros (exact duplicates, perfectly smooth actions) are drawn at the left edge.
            floor = values[finite & (values > 0)].min() / 2
            values = np.where(finite, np.maximum(values, floor), values)
        elif log:
            finite &= values > 0
        if not finite.any():
            ax.text(0.5, 0.5, "not available", ha="center", va="center", transform=ax.transAxes)
            ax.set_title(label, fontsize=9)
            continue
        v = values[finite]
        if log:
            edges = np.geomspace(v.min(), max(v.max(), v.min() * 1.01), 40)
            ax.set_xscale("log")
        else:
            lo, hi = v.min(), v.max()
            edges = np.linspace(lo, hi if hi > lo else lo + 1, 40)
        for name, sel in groups:
            data = values[finite & sel]
            if len(data):
                ax.hist(data, bins=edges, histtype="step", linewidth=1.5, label=f"{name} ({len(data)})")
        for x in lines:
            if x is not None and (not log or x > 0):
                ax.axvline(x, color="red", linestyle="--", linewidth=1.2)
        ax.set_title(label, fontsize=9)
        ax.set_ylabel("episodes", fontsize=8)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.965), ncol=min(6, len(handles)), fontsize=8)
    fig.suptitle(
        f"curation signals: {int(curation.kept.sum())}/{len(curation.kept)} episodes kept (red dashes: thresholds)", y=0.995, fontsize=10
    )
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return save_figure(fig, path, dpi=90)
