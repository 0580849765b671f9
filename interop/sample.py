"""A random store that exercises every kind of feature and per-episode column a converter must carry.

Used by the round-trip tests of every format: low-dim float32 obs (with and without per-dimension
names, a scalar, a matrix), float64/int16/bool obs, a uint8 RGB camera, ``sim.state`` (float64),
an ``info.*`` key, an ``ee7`` action with params, episodes of varied lengths, success/seed/source/
operator/task, masks, scores, an int32 column and a column with nulls. Deterministic for a seed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta


def sample_meta(image: tuple[int, int] = (12, 10)) -> StoreMeta:
    return StoreMeta(
        fps=20.0,
        features={
            "obs.joint_pos": FeatureSpec((7,), "float32", "arm joint angles", "rad", names=tuple(f"j{i}" for i in range(7))),
            "obs.ee_pos": FeatureSpec((3,), "float32", "end-effector position, base frame", "m"),
            "obs.gripper": FeatureSpec((), "float32", "gripper opening", "m"),
            "obs.rot": FeatureSpec((2, 3), "float32", "first two rotation-matrix columns"),
            "obs.goal64": FeatureSpec((3,), "float64", "goal position (double)", "m"),
            "obs.contacts": FeatureSpec((2,), "int16", "contact counts"),
            "obs.grasped": FeatureSpec((1,), "bool", "object between the fingers"),
            "obs.image_front": FeatureSpec((*image, 3), "uint8", "front camera", "rgb"),
            "sim.state": FeatureSpec((17,), "float64", "MuJoCo integration state"),
            "info.ee_target": FeatureSpec((7,), "float32", "commanded EE target (pos + quat wxyz)"),
        },
        action=ActionSpec(
            "ee7", ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"), ("m",) * 3 + ("rad",) * 3 + ("1",),
            frame="base", description="delta EE pose", params={"rotation": "rpy_xyz", "gripper_range": [0, 1]},
        ),
        robot={"name": "panda_prim", "config": "builtin"},
        task={"name": "pick", "options": {"cube_size": 0.04}, "horizon": 160},
        provenance=[{"op": "collect", "note": "synthetic"}],
    )


def sample_episode(rng: np.random.Generator, meta: StoreMeta, length: int) -> dict[str, np.ndarray]:
    data: dict[str, np.ndarray] = {}
    for key, spec in meta.features.items():
        shape = (length, *spec.shape)
        if spec.dtype == "uint8":
            data[key] = rng.integers(0, 256, size=shape, dtype=np.uint8)
        elif spec.dtype == "bool":
            data[key] = rng.random(shape) < 0.5
        elif np.dtype(spec.dtype).kind == "i":
            data[key] = rng.integers(-50, 50, size=shape).astype(spec.dtype)
        else:
            data[key] = rng.normal(size=shape).astype(spec.dtype)
    return data


def make_sample_store(path: str | Path, episodes: int = 6, seed: int = 0, image: tuple[int, int] = (12, 10)) -> Path:
    """Write the sample store at ``path`` (replacing one there) and return the path."""
    rng = np.random.default_rng(seed)
    meta = sample_meta(image)
    with EpisodeStore.create(path, meta, overwrite=True) as store:
        batch = []
        for i in range(episodes):
            data = sample_episode(rng, meta, int(rng.integers(3, 40)))
            info = {"success": bool(i % 3), "seed": 100 + i, "source": ["scripted", "kinesthetic"][i % 2],
                    "operator": ["expert", "poor"][i % 2], "task": "pick" if i < episodes - 1 else "pick_alt",
                    "dagger_round": i // 2}
            if i % 2 == 0:
                info["note"] = f"episode {i}"  # a string column with nulls on odd episodes
            batch.append((data, info))
        store.append_episodes(batch)
        store.set_mask("train", np.arange(episodes) % 4 != 3)
        store.set_mask("valid", np.arange(episodes) % 4 == 3)
        store.set_mask("empty", np.zeros(episodes, bool))
        store.set_column("score.jerk", rng.random(episodes))
        store.set_column("count32", np.arange(episodes, dtype=np.int32))
    return Path(path)
