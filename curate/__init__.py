"""demo.curate: per-episode quality signals and the filters of `demo curate`.

Entry points: :func:`demo.curate.curate.curate` (analyse a store and write the curated copy and/or a
mask), :func:`demo.curate.curate.analyse` (signals and decisions only), :mod:`demo.curate.report`
(tables, JSON, PNG), one module per signal family under :mod:`demo.curate.signals`.
"""

from demo.curate.curate import ALL_SIGNALS, CurateConfig, Curation, analyse, compute_signals, decide

__all__ = ["ALL_SIGNALS", "CurateConfig", "Curation", "analyse", "compute_signals", "decide"]
