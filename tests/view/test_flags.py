"""Curation flags as the viewer shows them next to each episode."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.interop.sample import make_sample_store
from demo.store import EpisodeStore
from demo.view.flags import EpisodeFlags


def test_labels_details_and_table(tmp_path: Path) -> None:
    store = EpisodeStore.open(make_sample_store(tmp_path / "s.zarr", episodes=9, seed=3))
    flags = EpisodeFlags(store)
    labels = flags.labels()
    assert len(labels) == 9 and len(set(labels)) == 9
    for i, label in enumerate(labels):
        assert label.startswith(f"{i}: ")
        assert ("ok" in label) == bool(store.column("success")[i])
        assert f"{store.episode_lengths[i]}f" in label
        assert ("train" in label) == bool(store.mask("train")[i]) and ("valid" in label) == bool(store.mask("valid")[i])
        assert "empty" not in label
    details = flags.details(3)
    assert "Episode 3" in details and "valid ✔" in details and "train ✘" in details
    assert f"jerk = {store.column('score.jerk')[3]:.3g}" in details
    table = flags.table(around=8, rows=4)
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| ep")]
    assert [r.split("|")[1].strip() for r in rows] == ["5", "6", "7", "**8**"]
    assert "episodes 5-8 of 9" in table
    assert np.array_equal(flags.masks["empty"], np.zeros(9, bool))


def test_curation_drop_reasons_are_shown(tmp_path: Path) -> None:
    from demo.curate import synthetic
    from demo.curate.curate import curate

    episodes = synthetic.mixed_episodes(12, seed=2)
    episodes[0][1]["success"] = False
    path = synthetic.write_store(tmp_path / "mixed.zarr", episodes)
    with EpisodeStore.open(path) as store:
        assert EpisodeFlags(store).reasons is None  # never curated: no "kept"/"dropped" claims
    curation = curate(path, mask="curated")
    store = EpisodeStore.open(path)
    flags = EpisodeFlags(store)
    dropped = [i for i in range(flags.n) if not curation.kept[i]]
    assert 0 in dropped and len(dropped) < flags.n
    for i in range(flags.n):
        details = flags.details(i)
        if i in dropped:
            assert flags.dropped_for(i) == "; ".join(curation.reasons[i]) != ""
            assert f"curation **dropped** it: {flags.dropped_for(i)}" in details
            assert " dropped: " in flags.label(i)
        else:
            assert flags.dropped_for(i) == "" and "curation kept it" in details and "dropped" not in flags.label(i)
    assert "failed" in flags.dropped_for(0)
    header = flags.table(around=0).splitlines()[0]
    assert "dropped for" in header
    store.close()


def test_an_episodes_instruction_is_shown(tmp_path: Path) -> None:
    from demo.cli.main import main

    out = tmp_path / "told.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "2", "--workers", "0", "--instruction",
                 "Touch the target", "--out", str(out)]) == 0
    with EpisodeStore.open(out) as store:
        assert "instruction: *Touch the target*" in EpisodeFlags(store).details(1)
    with EpisodeStore.open(make_sample_store(tmp_path / "s.zarr", episodes=2, seed=3)) as store:
        assert "instruction" not in EpisodeFlags(store).details(0)  # none told
