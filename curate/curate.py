"""Curation: compute every quality signal, decide what to keep, write the subset.

The pipeline reads top to bottom:

1. :func:`compute_signals`: load actions + low-dim observations once (:mod:`demo.curate.frames`)
   and compute every signal family (:mod:`demo.curate.signals`) for all episodes.
2. :func:`decide`: apply the filters of a :class:`CurateConfig`; every dropped episode gets the
   reason(s), every kept one an optional idle trim ``[trim_start, trim_stop)``.
3. :func:`curate`: the above, then write either a new store with the kept (trimmed) episodes
   (``out``, via ``copy_to`` with a provenance record) and/or ``score.<signal>`` columns plus the
   decision ``mask.<name>`` into the source store itself (``mask``). The source's frames are never
   modified.

Defaults are what a robot-learning engineer would want from a mixed-quality dataset: drop failures,
cut idle starts/ends, drop episodes that pause for more than a fifth of their time, are shaky,
disagree with the other demonstrators, take far longer than usual, or duplicate another. Short
episodes are not dropped for their length: a quick success is no flaw, and a truncated failure is
already dropped as a failure.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demo.curate.frames import GRIPPER_WORDS, FrameData, load_frames
from demo.curate.signals import Signal
from demo.curate.signals import consistency as consistency_signals
from demo.curate.signals import duplicates as duplicate_signals
from demo.curate.signals import idle as idle_signals
from demo.curate.signals import jerk as jerk_signals
from demo.curate.signals import outliers as outlier_signals
from demo.curate.signals import success as success_signals
from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.sim.foreign import ACTION_NAME as FOREIGN_ACTION
from demo.store.episode_table import REASONS_COLUMN
from demo.store import ActionSpec, EpisodeStore
from demo.store.location import StorePath, same_store, store_path

ALL_SIGNALS: tuple[Signal, ...] = (
    *success_signals.SIGNALS,
    *outlier_signals.SIGNALS,
    *idle_signals.SIGNALS,
    *jerk_signals.SIGNALS,
    *consistency_signals.SIGNALS,
    *duplicate_signals.SIGNALS,
)
REASONS = ("failed", "idle", "jerky", "inconsistent", "novel", "duplicate", "length", "near-miss")
# What compute_signals does, in order: one progress step each (stage "curate").
STEPS = ("load", "success", "idle", "jerk", "length", "consistency", "duplicates")


DEFAULT_MAX_JERK = 400.0


@dataclass
class CurateConfig:
    """Filters (``None`` switches one off) and the signals' hyperparameters."""

    drop_failed: bool = True
    trim_idle: bool = True  # cut idle runs at the start/end of kept episodes (an edit, recorded)
    max_idle: float | None = 0.2  # fraction of (trimmed) frames in mid-episode pauses
    # range/s^3 (see demo.curate.signals.jerk); at this default, off for a Gymnasium environment's own command
    # unless it names its arm dimensions positions (rad or m, as gym-aloha's joint targets): otherwise its units
    # are unknown, and the jerk of a velocity-like command, as Meta-World's scripted controllers switch it, says
    # nothing of shakiness (17 of 20 of their demonstrations read 1,000-7,000)
    max_jerk: float | None = DEFAULT_MAX_JERK
    min_consistency: float | None = 0.5  # fraction of sampled frames that agree with neighbours
    max_novelty: float | None = None  # mean distance to other episodes' states (normalised obs units)
    max_length_z: float | None = 3.5  # robust z of log length within the task; long side only (a quick success is no flaw)
    dedupe: bool = True  # keep the first of each group of (near-)duplicates
    min_time_left_s: float | None = None  # near-miss in time: success with less time to spare
    min_margin: float | None = None  # near-miss in space: success margin below this (task units)
    idle: idle_signals.IdleParams = field(default_factory=idle_signals.IdleParams)
    consistency: consistency_signals.ConsistencyParams = field(default_factory=consistency_signals.ConsistencyParams)
    duplicates: duplicate_signals.DuplicateParams = field(default_factory=duplicate_signals.DuplicateParams)

    def validate(self) -> None:
        for name in ("max_idle", "min_consistency"):
            v = getattr(self, name)
            if v is not None and not 0.0 <= v <= 1.0:
                raise DemoError(f"--{name.replace('_', '-')}", f"must be a fraction in [0, 1], got {v}")
        for name in ("max_jerk", "max_length_z", "min_time_left_s", "max_novelty"):
            v = getattr(self, name)
            if v is not None and not v >= 0.0:
                raise DemoError(f"--{name.replace('_', '-')}", f"must be >= 0, got {v}")
        if self.consistency.k < 1 or self.consistency.queries < 1:
            raise DemoError("--neighbours", "k and queries must be >= 1")
        if not self.consistency.agree_factor > 0:
            raise DemoError("--agree-factor", f"must be > 0, got {self.consistency.agree_factor}")
        if not self.duplicates.tol >= 0:
            raise DemoError("--dedupe-tol", f"must be >= 0, got {self.duplicates.tol}")
        if not (self.idle.speed > 0 and self.idle.min_run_s >= 0):
            raise DemoError("--idle-speed", "idle speed must be > 0 and the minimum pause >= 0")

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class Curation:
    """Signals and decisions for every episode of a store."""

    signals: dict[str, np.ndarray]  # name -> [E] float64 (see ALL_SIGNALS)
    kept: np.ndarray  # [E] bool
    reasons: list[list[str]]  # per episode, human-readable ("jerk 812 > 400")
    codes: list[list[str]]  # per episode, reason codes from REASONS
    trim: np.ndarray  # [E, 2] int64 episode-relative frame range kept, [0, length) when untrimmed
    lengths: np.ndarray  # [E] frames before trimming
    config: CurateConfig
    timing: dict[str, float]  # seconds per stage
    frames: int
    table: Any = None  # the source's episode table (pyarrow) as it was when analysed

    @property
    def trimmed(self) -> np.ndarray:
        """[E] bool: kept episodes whose frame range was cut."""
        return self.kept & ((self.trim[:, 0] > 0) | (self.trim[:, 1] < self.lengths))

    def frame_ranges(self) -> dict[int, tuple[int, int]]:
        return {int(i): (int(self.trim[i, 0]), int(self.trim[i, 1])) for i in np.flatnonzero(self.trimmed)}


def compute_signals(
    store: EpisodeStore, config: CurateConfig, progress: Progress | None = None, total: int = len(STEPS)
) -> tuple[dict[str, np.ndarray], FrameData, dict[str, float]]:
    """Every signal for every episode: ``(signals, frame data, seconds per stage)``.

    ``progress`` gets a tick (stage ``curate``, ``total`` steps in all) as each of :data:`STEPS` starts.
    """
    report = or_silent(progress)
    timing: dict[str, float] = {}
    signals: dict[str, np.ndarray] = {}

    def stage(name: str, fn: Callable[[], Any]) -> Any:
        report(Tick("curate", len(timing), total, {"step": name}))
        t0 = time.perf_counter()
        result = fn()
        timing[name] = time.perf_counter() - t0
        return result

    fd = stage("load", lambda: load_frames(store))
    tasks = store.column("task")
    signals.update(stage("success", lambda: success_signals.compute(store)))
    signals.update(stage("idle", lambda: idle_signals.compute(fd, config.idle)))
    signals.update(stage("jerk", lambda: jerk_signals.compute(fd)))
    trimmed_len = signals["trim_stop"] - signals["trim_start"] if config.trim_idle else fd.lengths
    signals.update(stage("length", lambda: outlier_signals.compute(trimmed_len, tasks)))
    signals.update(stage("consistency", lambda: consistency_signals.compute(fd, config.consistency)))
    signals.update(stage("duplicates", lambda: duplicate_signals.compute(fd, config.duplicates)))
    return signals, fd, timing


def decide(
    signals: dict[str, np.ndarray], lengths: np.ndarray, config: CurateConfig
) -> tuple[np.ndarray, list[list[str]], list[list[str]], np.ndarray]:
    """``(kept, reasons, codes, trim)`` from the signals and the config's filters."""
    e = len(lengths)
    reasons: list[list[str]] = [[] for _ in range(e)]
    codes: list[list[str]] = [[] for _ in range(e)]

    def flag(bad: np.ndarray, code: str, text: Callable[[int], str]) -> None:
        for i in np.flatnonzero(bad):
            codes[i].append(code)
            reasons[i].append(text(int(i)))

    s = signals
    success = s["success"] > 0.5
    if config.drop_failed:
        flag(~success, "failed", lambda i: "failed")
    idle_key = "pause_fraction" if config.trim_idle else "idle_fraction"
    if config.max_idle is not None:
        flag(s[idle_key] > config.max_idle, "idle", lambda i: f"idle {s[idle_key][i]:.0%} > {config.max_idle:.0%}")
    if config.max_jerk is not None:
        flag(s["jerk"] > config.max_jerk, "jerky", lambda i: f"jerk {s['jerk'][i]:.3g} > {config.max_jerk:.3g}")
    if config.min_consistency is not None:
        c = s["consistency"]
        flag(np.isfinite(c) & (c < config.min_consistency), "inconsistent",
             lambda i: f"consistency {c[i]:.2f} < {config.min_consistency:.2f}")
    if config.max_novelty is not None:
        nv = s["novelty"]
        flag(np.isfinite(nv) & (nv > config.max_novelty), "novel", lambda i: f"novelty {nv[i]:.2f} > {config.max_novelty:g}")
    if config.max_length_z is not None:
        z = s["length_z"]
        flag(z > config.max_length_z, "length", lambda i: f"length z {z[i]:+.1f} > {config.max_length_z:g}")
    if config.dedupe:
        dup = s["dup_of"]
        flag(dup >= 0, "duplicate", lambda i: f"duplicate of #{int(dup[i])}")
    if config.min_time_left_s is not None:
        t = s["time_left_s"]
        flag(success & np.isfinite(t) & (t < config.min_time_left_s), "near-miss",
             lambda i: f"near-miss: {t[i]:.2f} s left < {config.min_time_left_s:g} s")
    if config.min_margin is not None:
        m = s["margin"]
        flag(success & np.isfinite(m) & (m < config.min_margin), "near-miss",
             lambda i: f"near-miss: margin {m[i]:.3g} < {config.min_margin:g}")

    kept = np.array([not c for c in codes], dtype=bool)
    trim = np.stack([np.zeros(e, np.int64), np.asarray(lengths, np.int64)], axis=1)
    if config.trim_idle:
        trim = np.stack([s["trim_start"], s["trim_stop"]], axis=1).astype(np.int64)
    return kept, reasons, codes, trim


def commands_positions(action: ActionSpec) -> bool:
    """Whether the action's arm dimensions are positions, whose jerk is shakiness: demo's own actions, and a
    Gymnasium environment's where it names them in rad or m (its grippers left out, as the jerk leaves them)."""
    if action.name != FOREIGN_ACTION:
        return True
    arm = [u for n, u in zip(action.names, action.units) if not any(w in n.lower() for w in GRIPPER_WORDS)]
    return bool(arm) and all(u in ("rad", "m") for u in arm)


def analyse(
    store: EpisodeStore, config: CurateConfig | None = None, progress: Progress | None = None, total: int = len(STEPS)
) -> Curation:
    """Signals and decisions for ``store`` without writing anything (``progress``: see :func:`compute_signals`)."""
    config = config or CurateConfig()
    config.validate()
    if config.max_jerk == DEFAULT_MAX_JERK and not commands_positions(store.meta.action):
        config = dataclasses.replace(config, max_jerk=None)  # see CurateConfig.max_jerk
    signals, fd, timing = compute_signals(store, config, progress, total)
    t0 = time.perf_counter()
    kept, reasons, codes, trim = decide(signals, fd.lengths, config)
    timing["decide"] = time.perf_counter() - t0
    or_silent(progress)(Tick("curate", len(STEPS), total, {"kept": f"{int(kept.sum())}/{len(kept)}"}))
    return Curation(signals, kept, reasons, codes, trim, fd.lengths, config, timing, fd.num_frames, store.table)


def score_columns(curation: Curation, episodes: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``score.<signal>`` columns (float64) for the chosen episodes (all when None)."""
    sel = slice(None) if episodes is None else episodes
    names = [sig.name for sig in ALL_SIGNALS]
    return {f"score.{n}": np.asarray(curation.signals[n], dtype=np.float64)[sel] for n in names}


def provenance_record(curation: Curation, source: StorePath, mask: str | None) -> dict[str, Any]:
    counts = {code: sum(code in c for c in curation.codes) for code in REASONS}
    return {
        "op": "curate",
        "from": str(source),
        "mask": mask,
        "kept": int(curation.kept.sum()),
        "dropped": int((~curation.kept).sum()),
        "dropped_by_reason": counts,
        "trimmed": int(curation.trimmed.sum()),
        "config": curation.config.to_json(),
    }


def curate(
    source: str | Path,
    out: str | Path | None = None,
    *,
    mask: str | None = None,
    config: CurateConfig | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> Curation:
    """Curate the store at ``source``.

    ``out``: write the kept episodes (idle-trimmed when ``config.trim_idle``) to a new store there,
    with ``score.*`` columns and a provenance record. ``mask``: write ``score.*`` columns and
    ``mask.<mask>`` (= kept) into the source store, plus ``curate.trim_start``/``curate.trim_stop``
    (the range a trim would keep; frames are not edited in place) and ``curate.reasons`` (why
    each episode was dropped, "" when kept). Neither: analyse only. ``progress``: one tick per
    step (stage ``curate``): :data:`STEPS`, then ``write`` when there is anything to write.
    """
    source = store_path(source)
    if mask is not None and (not mask or not all(ch.isalnum() or ch in "_-" for ch in mask)):
        raise DemoError("--mask", f"mask name {mask!r} must be letters, digits, '_' or '-'")
    if out is not None and same_store(store_path(out), source):
        raise DemoError(out, "is the source store; curation never overwrites its input (use --mask NAME to mark it in place)")
    report = or_silent(progress)
    total = len(STEPS) + int(out is not None or mask is not None)
    with EpisodeStore.open(source, "a" if mask else "r") as store:
        curation = analyse(store, config, progress, total)
        t0 = time.perf_counter()
        kept = {"kept": f"{int(curation.kept.sum())}/{len(curation.kept)}"}
        if total > len(STEPS):
            report(Tick("curate", len(STEPS), total, {**kept, "step": "write"}))
        if out is not None:
            chosen = np.flatnonzero(curation.kept)
            if len(chosen) == 0:
                raise DemoError(source, "curation kept no episode; loosen the filters (see the report) before writing --out")
            ranges = curation.frame_ranges() if curation.config.trim_idle else None
            record = provenance_record(curation, source, mask)
            with store.copy_to(out, chosen, frame_ranges=ranges, provenance=record, overwrite=overwrite) as copy:
                for name, values in score_columns(curation, chosen).items():
                    copy.set_column(name, values)
        if mask is not None:
            for name, values in score_columns(curation).items():
                store.set_column(name, values)
            store.set_column("curate.trim_start", curation.trim[:, 0])
            store.set_column("curate.trim_stop", curation.trim[:, 1])
            store.set_column(REASONS_COLUMN, ["; ".join(r) for r in curation.reasons])
            store.set_mask(mask, curation.kept)
            store.update_meta(provenance=[*store.meta.provenance, provenance_record(curation, source, mask)])
        curation.timing["write"] = time.perf_counter() - t0
        if total > len(STEPS):
            report(Tick("curate", total, total, kept))
    return curation
