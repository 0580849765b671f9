"""The curation pipeline: decisions on a mixed dataset, a trimmed copy with provenance, masks in
place, the source left untouched, and clear errors for bad input."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from demo.curate import synthetic
from demo.curate.curate import CurateConfig, analyse, curate
from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta


def tree_hash(path: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(path.rglob("*")):
        if p.is_file() and p.name != ".lock":
            h.update(str(p.relative_to(path)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """48 episodes (12 per operator profile), two failures, one duplicate of episode 0 (48), and two
    clean expert episodes with a 1.5 s idle start (49, 50)."""
    episodes = synthetic.mixed_episodes(48, seed=3)
    episodes[4][1]["success"] = False  # an expert failure
    episodes[9][1]["success"] = False  # a good operator's failure
    episodes.append(({k: v.copy() for k, v in episodes[0][0].items()}, {**episodes[0][1], "seed": 100}))
    rng = np.random.default_rng(9)
    for seed in (101, 102):
        data = synthetic.episode(rng, synthetic.Flaws(idle_start_s=1.5))
        episodes.append((data, {"success": True, "seed": seed, "source": "synthetic", "operator": "expert"}))
    return synthetic.write_store(tmp_path_factory.mktemp("mixed") / "mixed.zarr", episodes)


def test_mixed_dataset_decisions(mixed: Path) -> None:
    with EpisodeStore.open(mixed) as store:
        c = analyse(store)
        ops = store.column("operator")
    assert not c.kept[[4, 9]].any() and all("failed" in c.codes[i] for i in (4, 9))
    assert not c.kept[48] and c.codes[48] == ["duplicate"] and c.reasons[48] == ["duplicate of #0"]
    expert = (ops == "expert") & ~np.isin(np.arange(51), [4, 48])
    assert c.kept[expert].mean() >= 0.9
    assert (~c.kept[ops == "poor"]).mean() >= 0.9
    assert all(c.reasons[i] for i in np.flatnonzero(~c.kept))  # every drop says why
    # Idle starts of 1 s or more are trimmed (the poor operators' too, though they are dropped).
    starts = c.signals["idle_start_s"]
    assert (c.trim[starts >= 1.0, 0] > 0).all()
    assert c.kept[[49, 50]].all() and c.trimmed[[49, 50]].all()
    # 1.5 s at 20 fps, less the 0.1 s kept, plus the slow first frames of the minimum-jerk start.
    assert (28 <= c.trim[[49, 50], 0]).all() and (c.trim[[49, 50], 0] <= 34).all()


def test_copy_is_trimmed_scored_and_recorded(mixed: Path, tmp_path: Path) -> None:
    before = tree_hash(mixed)
    c = curate(mixed, tmp_path / "out.zarr")
    assert tree_hash(mixed) == before  # the source is never modified
    kept = np.flatnonzero(c.kept)
    with EpisodeStore.open(tmp_path / "out.zarr") as out, EpisodeStore.open(mixed) as src:
        assert out.num_episodes == len(kept)
        np.testing.assert_array_equal(out.column("source_episode"), kept)
        np.testing.assert_array_equal(out.episode_lengths, c.trim[kept, 1] - c.trim[kept, 0])
        for j, i in enumerate(kept):
            a, b = c.trim[i]
            np.testing.assert_array_equal(out.read_episode(j, ["action"])["action"], src.read_episode(int(i), ["action"])["action"][a:b])
        np.testing.assert_allclose(out.column("score.jerk"), c.signals["jerk"][kept])
        record = out.meta.provenance[-1]
        assert record["op"] == "curate" and record["kept"] == len(kept) and record["from"] == str(mixed)
        assert record["config"]["max_jerk"] == CurateConfig().max_jerk
        trimmed = [t for t in out.column("trimmed_from") if t]
        assert len(trimmed) == int(c.trimmed.sum()) > 0


def test_mask_in_place_leaves_frames_alone(mixed: Path, tmp_path: Path) -> None:
    copy = tmp_path / "copy.zarr"
    with EpisodeStore.open(mixed) as src:
        src.copy_to(copy).close()
    data_before = tree_hash(copy / "data")
    c = curate(copy, mask="curated")
    assert tree_hash(copy / "data") == data_before
    with EpisodeStore.open(copy) as store:
        np.testing.assert_array_equal(store.mask("curated"), c.kept)
        np.testing.assert_array_equal(store.select("curated"), np.flatnonzero(c.kept))
        np.testing.assert_allclose(store.column("score.consistency"), c.signals["consistency"])
        np.testing.assert_array_equal(store.column("curate.trim_start"), c.trim[:, 0])
        assert store.meta.provenance[-1]["mask"] == "curated"


def test_filters_can_be_switched_off(mixed: Path) -> None:
    off = CurateConfig(drop_failed=False, trim_idle=False, max_idle=None, max_jerk=None, min_consistency=None,
                       max_length_z=None, dedupe=False)
    with EpisodeStore.open(mixed) as store:
        c = analyse(store, off)
    assert c.kept.all() and not c.trimmed.any()


def test_image_store_is_curated_from_lowdim_keys(tmp_path: Path) -> None:
    base = synthetic.meta()
    meta = StoreMeta(fps=20.0, features={**{k: v for k, v in base.features.items() if k != "action"},
                                         "obs.image_front": FeatureSpec((8, 8, 3), "uint8", "camera", "rgb")},
                     action=base.action)
    rng = np.random.default_rng(0)
    with EpisodeStore.create(tmp_path / "img.zarr", meta) as store:
        for flaws in [synthetic.Flaws()] * 6 + [synthetic.Flaws(jitter=0.05)]:
            data = synthetic.episode(rng, flaws)
            data["obs.image_front"] = rng.integers(0, 255, (len(data["action"]), 8, 8, 3), dtype=np.uint8)
            store.append_episode(data, success=True)
    c = curate(tmp_path / "img.zarr", tmp_path / "img_out.zarr")
    print(c.reasons, c.signals["consistency"], c.signals["coverage"]); assert c.kept[:6].all() and not c.kept[6] and "jerky" in c.codes[6]
    with EpisodeStore.open(tmp_path / "img_out.zarr") as out:
        assert out.num_episodes == 6 and "obs.image_front" in out.meta.features


def test_bad_input(mixed: Path, tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="no such store"):
        curate(tmp_path / "missing.zarr", tmp_path / "o.zarr")
    with pytest.raises(DemoError, match="is the source store"):
        curate(mixed, mixed)
    with pytest.raises(DemoError, match="kept no episode"):
        curate(mixed, tmp_path / "none.zarr", config=CurateConfig(max_jerk=0.0))
    assert not (tmp_path / "none.zarr").exists()
    with pytest.raises(DemoError, match="fraction"):
        curate(mixed, config=CurateConfig(max_idle=1.5))
    with pytest.raises(DemoError, match="mask name"):
        curate(mixed, mask="bad name!")
    (tmp_path / "exists.zarr").mkdir()
    (tmp_path / "exists.zarr" / "f").write_text("x")
    with pytest.raises(DemoError, match="already exists"):
        curate(mixed, tmp_path / "exists.zarr")
    empty = tmp_path / "empty.zarr"
    EpisodeStore.create(empty, StoreMeta(fps=10.0, features={}, action=ActionSpec("joint_pos", ("a",), ("rad",)))).close()
    with pytest.raises(DemoError, match="has no episodes"):
        curate(empty)
