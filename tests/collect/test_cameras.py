"""Collection with cameras: worker processes store the same bytes as one process, and `demo info`
states each camera's bytes per frame, raw and as stored on disk."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.store import EpisodeStore

CAMERAS = (("front", 32, 24), ("wrist", 32, 32))  # (name, width, height)


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("cameras")
    config = CollectConfig(task="reach", episodes=2, seed=3, cameras=CAMERAS)
    collect_scripted(config, root / "inline.zarr", workers=0)
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=3, cameras=CAMERAS), root / "two.zarr", workers=2)
    return root / "inline.zarr", root / "two.zarr"


@pytest.mark.slow
def test_two_workers_store_the_same_bytes(stores: tuple[Path, Path]) -> None:
    with EpisodeStore.open(stores[0]) as a, EpisodeStore.open(stores[1]) as b:
        assert a.num_episodes == b.num_episodes == 2
        assert a.column("crc32").tolist() == b.column("crc32").tolist()
        for key in ("obs.image_front", "obs.image_wrist"):
            images = a.load([key])[0][key]
            assert images.shape[1:] == ((24, 32, 3) if key.endswith("front") else (32, 32, 3))
            assert images.std() > 5  # a rendered scene, not a blank buffer
            assert np.array_equal(images, b.load([key])[0][key])


@pytest.mark.slow
def test_info_states_bytes_per_frame(stores: tuple[Path, Path], capfd: pytest.CaptureFixture) -> None:
    path = stores[0]
    capfd.readouterr()
    assert main(["info", str(path), "--json", "-"]) == 0
    out, err = capfd.readouterr()
    sizes = json.loads(out)["camera_bytes"]
    frames = json.loads(out)["frames"]
    assert "camera bytes per frame" in err and "obs.image_wrist" in err
    total_stored = 0
    for key, (w, h) in {"obs.image_front": (32, 24), "obs.image_wrist": (32, 32)}.items():
        s = sizes["per_camera"][key]
        on_disk = sum(f.stat().st_size for f in (path / "data" / key / "c").rglob("*") if f.is_file())
        assert s["shape"] == [h, w, 3] and s["raw_bytes_per_frame"] == h * w * 3
        assert s["stored_bytes_per_frame"] == pytest.approx(on_disk / frames)
        assert s["compression_ratio"] == pytest.approx(h * w * 3 * frames / on_disk) and s["compression_ratio"] > 1
        total_stored += on_disk
    assert sizes["total"]["raw_bytes_per_frame"] == (24 + 32) * 32 * 3
    assert sizes["total"]["stored_bytes_per_frame"] == pytest.approx(total_stored / frames)


def test_info_without_cameras(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    collect_scripted(CollectConfig(task="reach", episodes=1, seed=0), tmp_path / "s.zarr", workers=0)
    capfd.readouterr()
    assert main(["info", str(tmp_path / "s.zarr"), "--json", "-"]) == 0
    out, err = capfd.readouterr()
    assert json.loads(out)["camera_bytes"] == {} and "camera bytes" not in err
