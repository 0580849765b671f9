"""The bytes a refactoring must not change: crc32 of collected stores and of seeded training weights.

Run it on two commits and compare the JSON (``python tools/fingerprint.py OUT.json``). It collects
every task, a camera store, a VR and a kinesthetic store, and trains a seeded BC and diffusion run
for a few hundred steps; each file's crc32 is recorded, except the files that hold wall-clock
times (``run.json``'s timings, store provenance times), which are listed by name only.

It drives the command line only (``python -m demo ...``), so it runs unchanged on any layout.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path

TASKS = ("reach", "pick", "push", "avoid", "stack")
# Files whose bytes carry the time of day or seconds elapsed (provenance times, the metrics' wall-clock
# column, which train_state.pt holds too): compared by presence, not content. The weights
# (policy.safetensors) and every array chunk are compared by content.
VOLATILE = ("zarr.json", "run.json", "metrics.json", "metrics.jsonl", "summary.json", "train_state.pt",
            "train_curves.png", "configuration.json")


def demo(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "demo", *args], check=True, stdout=subprocess.DEVNULL)


def crc_tree(root: Path) -> dict[str, str]:
    out = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        rel = str(path.relative_to(root))
        out[rel] = "volatile" if path.name in VOLATILE else format(zlib.crc32(path.read_bytes()), "08x")
    return out


def main(out_json: str) -> None:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    os.environ.update(env)
    result: dict[str, dict[str, str]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for task in TASKS:
            demo("collect", "--task", task, "--episodes", "4", "--seed", "3", "--out", str(work / f"{task}.zarr"))
        demo("collect", "--task", "pick", "--episodes", "2", "--seed", "3", "--camera", "front@32x32",
             "--out", str(work / "camera.zarr"))
        code = "from demo.collect.human_files import write_human_files; import sys; write_human_files(sys.argv[1], task='reach', episodes=1, seed=5)"
        subprocess.run([sys.executable, "-c", code, str(work / "human")], check=True)
        demo("collect", "--source", "vr", "--task", "reach", "--input", str(work / "human" / "POSES.jsonl"),
             "--scale", str(1 / 1.3), "--out", str(work / "vr.zarr"))
        demo("collect", "--source", "kinesthetic", "--task", "reach", "--input", str(work / "human" / "JOINTS.csv"),
             "--out", str(work / "kinesthetic.zarr"))
        demo("train", str(work / "pick.zarr"), "--steps", "200", "--seed", "1", "--out", str(work / "bc"))
        demo("train", str(work / "avoid.zarr"), "--algo", "diffusion", "--steps", "100", "--seed", "1",
             "--out", str(work / "diffusion"))
        for name in [*TASKS, "camera", "vr", "kinesthetic"]:
            result[f"{name}.zarr"] = crc_tree(work / f"{name}.zarr")
        for name in ("bc", "diffusion"):
            result[name] = crc_tree(work / name)
    Path(out_json).write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    print(f"{sum(len(v) for v in result.values())} files fingerprinted -> {out_json}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "fingerprint.json")
