"""The shift suite: ``demo eval RUN --shift KIND --level A..B``, success against the level of one
distribution shift at a time (:mod:`demo.sim.randomize`: lighting, camera, texture, friction, mass,
latency), each cell a full :func:`demo.evaluation.evaluate.evaluate` on the same evaluation seeds, so
every level starts from the same states; level 0 (the nominal scene) is evaluated once and shared by
every shift. A robustness table, JSON, and a figure (one line per shift).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from demo.errors import DemoError
from demo.evaluation.evaluate import EvalConfig, evaluate
from demo.figures import success_lines
from demo.progress import Progress
from demo.sim.randomize import KINDS, MAX_LEVEL

CELL_KEYS = ("episodes", "successes", "success_rate", "ci95", "mean_length", "failures")


def parse_shifts(shifts: Sequence[str]) -> tuple[str, ...]:
    """``--shift`` values (repeatable; ``all`` for every kind) as kinds, in :data:`KINDS` order."""
    chosen = set()
    for name in shifts:
        if name == "all":
            chosen.update(KINDS)
        elif name in KINDS:
            chosen.add(name)
        else:
            raise DemoError("--shift", f"unknown shift {name!r} (choose from {', '.join(KINDS)}, all)")
    return tuple(k for k in KINDS if k in chosen)


def parse_levels(text: str) -> tuple[int, ...]:
    """``--level``: one level ``N`` or a range ``A..B`` (0 .. :data:`MAX_LEVEL`)."""
    first, dots, last = text.partition("..")
    try:
        lo, hi = int(first), int(last if dots else first)
    except ValueError:
        raise DemoError("--level", f"{text!r} is not a level N or a range A..B") from None
    if not 0 <= lo <= hi <= MAX_LEVEL:
        raise DemoError("--level", f"{text!r}: levels run from 0 to {MAX_LEVEL}")
    return tuple(range(lo, hi + 1))


def evaluate_shifts(config: EvalConfig, kinds: Sequence[str], levels: Sequence[int],
                    progress: Progress | None = None) -> dict[str, Any]:
    """Every (kind, level) cell of the suite; ``config`` as :func:`evaluate` takes it (its ``randomize``
    is replaced cell by cell). Returns ``{"shifts": {kind: {level: cell}}, "levels", "episodes", "run",
    "seed", "seconds"}``, a cell holding :data:`CELL_KEYS` of the evaluation."""
    if not kinds:
        raise DemoError("--shift", "names no shift")
    nominal: dict[str, Any] | None = None
    shifts: dict[str, dict[int, dict[str, Any]]] = {}
    seconds = 0.0
    for kind in kinds:
        for level in levels:
            if level == 0 and nominal is not None:
                result = nominal
            else:
                result = evaluate(dataclasses.replace(config, randomize={kind: level} if level else None), progress)
                seconds += result["seconds"]
                nominal = result if level == 0 else nominal
            shifts.setdefault(kind, {})[level] = {k: result[k] for k in CELL_KEYS}
    return {"run": config.run, "seed": config.seed, "episodes": config.episodes, "levels": list(levels),
            "shifts": shifts, "seconds": seconds}


def plot_shifts(result: dict[str, Any], path: str | Path) -> Path:
    """Success against level, one line per shift, with the 95% intervals as bands."""
    series = {kind: [(lv, c["success_rate"], *c["ci95"]) for lv, c in cells.items()]
              for kind, cells in result["shifts"].items()}
    return success_lines(series, path, "shift level", f"{Path(result['run']).name}: {result['episodes']} episodes "
                         "per cell", xticks=list(result["levels"]))
