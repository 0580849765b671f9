"""Opening a store to record into: create it, or append after checking it records the same thing.

Collection (``demo collect``, ``demo teleop``) and evaluation (``demo eval --record``) both record
episodes this way, so an append that would mix tasks, robots or features is refused the same way.
"""

from __future__ import annotations

from demo.errors import DemoError
from demo.store.episode_store import EpisodeStore, StoreMeta
from demo.store.layout import EXISTS
from demo.store.location import StorePath, store_path
from demo.store.robot_files import same_robot


def open_output(out: str | StorePath, meta: StoreMeta, append: bool, overwrite: bool) -> EpisodeStore:
    """Create the output store (a local path or a URL), or open it to append after checking it records the same thing.

    Either way the store's writer lock is held from the start (another writer, ``--overwrite``
    included, is refused); a refused append writes nothing. A created store replaces what was at
    ``out`` only with its first committed episode: close it with ``EpisodeStore.abandon`` (or leave
    a ``with`` block by the exception) when collection fails before then, and nothing is left.
    """
    out = store_path(out)
    if append and out.exists():
        store = EpisodeStore.open(out, "a")
        have = store.meta
        mismatch = [
            name
            for name, a, b in [
                ("task", (have.task or {}).get("name"), (meta.task or {}).get("name")),
                ("task options", (have.task or {}).get("options"), (meta.task or {}).get("options")),
                ("robot", same_robot(have.robot, meta.robot), True),
                ("features", {k: v.to_json() for k, v in have.features.items()},
                 {k: v.to_json() for k, v in meta.features.items()}),
                ("action", have.action.to_json(), meta.action.to_json()),
            ]
            if a != b
        ]
        if mismatch:
            store.abandon()
            raise DemoError(out, f"cannot append: the store records a different {', '.join(mismatch)}")
        store.update_meta(provenance=[*have.provenance, *meta.provenance])
        return store
    try:
        return EpisodeStore.create(out, meta, overwrite=overwrite)
    except DemoError as exc:
        if exc.problem != EXISTS:
            raise
        # A recording command can add to what is there: say so (the store layer knows no --append).
        raise DemoError(exc.where, "already exists (pass --append to add episodes to it, --overwrite to replace it, "
                                   "or choose another --out)", exc.exit_code) from None
