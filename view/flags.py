"""Curation flags of each episode, as the viewer shows them: success, masks (``mask.*``), scores
(``score.*``) and, after ``demo curate --mask``, why curation dropped it (``curate.reasons``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from demo.store import EpisodeStore
from demo.store.episode_table import REASONS_COLUMN, SCORE_PREFIX
from demo.store.instructions import INSTRUCTION_COLUMN

LABEL_REASON_CHARS = 40  # a dropdown entry shows this much of the drop reasons; the details show all


class EpisodeFlags:
    """Per-episode success, mask membership, score values and curation drop reasons of a store, read once."""

    def __init__(self, store: EpisodeStore):
        self.n = store.num_episodes
        self.success = store.column("success").astype(bool) if self.n else np.zeros(0, bool)
        self.lengths = store.episode_lengths
        self.masks = {name: store.mask(name) for name in store.mask_names()}
        self.scores = {
            c[len(SCORE_PREFIX):]: np.asarray(store.column(c), dtype=np.float64)
            for c in store.table.column_names if c.startswith(SCORE_PREFIX)
        }
        # None: never curated with --mask; else per episode "" (kept) or "reason; reason" (dropped).
        self.reasons: list[str] | None = None
        if REASONS_COLUMN in store.table.column_names:
            self.reasons = ["" if r is None else str(r) for r in store.column(REASONS_COLUMN).tolist()]
        self._info = store

    def masks_of(self, i: int) -> list[str]:
        return [name for name, member in self.masks.items() if member[i]]

    def dropped_for(self, i: int) -> str:
        """Why curation dropped episode ``i`` ("" when it was kept or the store was never curated)."""
        return self.reasons[i] if self.reasons is not None else ""

    def label(self, i: int) -> str:
        """One dropdown line: index, success mark, length, the masks it is in, why curation dropped it."""
        mark = "ok" if self.success[i] else "FAIL"
        masks = ",".join(self.masks_of(i))
        why = self.dropped_for(i)
        if len(why) > LABEL_REASON_CHARS:
            why = why[: LABEL_REASON_CHARS - 3] + "..."
        return f"{i}: {mark} {int(self.lengths[i])}f" + (f" [{masks}]" if masks else "") + (f" dropped: {why}" if why else "")

    def labels(self) -> list[str]:
        return [self.label(i) for i in range(self.n)]

    def details(self, i: int) -> str:
        """Markdown for the current episode: its info, every mask (in/out) and every score."""
        info: dict[str, Any] = self._info.episode_info(i)
        lines = [
            f"**Episode {i}** of {self.n}: {'success' if self.success[i] else '**failure**'}, "
            f"{int(self.lengths[i])} frames ({float(info.get('duration_s', 0)):.2f} s)",
            f"source `{info.get('source', '')}`, operator `{info.get('operator', '') or '-'}`, seed {info.get('seed', -1)}",
        ]
        if info.get(INSTRUCTION_COLUMN):
            lines.append(f"instruction: *{info[INSTRUCTION_COLUMN]}*")
        if self.masks:
            lines.append("masks: " + ", ".join(f"{name} {'✔' if member[i] else '✘'}" for name, member in self.masks.items()))
        if self.reasons is not None:
            why = self.dropped_for(i)
            lines.append(f"curation **dropped** it: {why}" if why else "curation kept it")
        if self.scores:
            lines.append("scores: " + ", ".join(f"{name} = {_fmt(v[i])}" for name, v in self.scores.items()))
        return "  \n".join(lines)

    def table(self, around: int, rows: int = 40) -> str:
        """Markdown table of up to ``rows`` episodes around ``around``, one row per episode with its flags."""
        start = max(0, min(around - rows // 2, self.n - rows))
        stop = min(self.n, start + rows)
        score_names = list(self.scores)[:4]
        why = ["dropped for"] if self.reasons is not None else []
        header = ["ep", "ok", "len", "masks", *why, *score_names]
        out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for i in range(start, stop):
            ep = f"**{i}**" if i == around else str(i)
            cells = [ep, "✔" if self.success[i] else "✘", str(int(self.lengths[i])), ",".join(self.masks_of(i)) or "-"]
            cells += [(self.dropped_for(i) or "-").replace("|", "/")] if why else []
            cells += [_fmt(self.scores[s][i]) for s in score_names]
            out.append("| " + " | ".join(cells) + " |")
        if stop - start < self.n:
            out.append(f"\nepisodes {start}-{stop - 1} of {self.n}")
        return "\n".join(out)


def _fmt(v: float) -> str:
    return "-" if not np.isfinite(v) else f"{v:.3g}"
