"""One policy across robots: BC on the union of two arms' ``ee7`` demonstrations, evaluated on each arm.

For the task (``pick``) and two arms (the built-in 7-DOF Panda and robosuite's 6-DOF UR5e, both at
their default base pose, so the scene frame the observations are in is each arm's base frame, the
frame of ``ee7``):

1. collect ``demos`` scripted demonstrations per arm (``demo collect --robot``) and convert each store
   to ``ee7`` (``demo convert --to ee7``: end-effector deltas of the commanded pose, base frame);
2. train BC (its default chunks and ensembling) on

   a. the **union** of both arms' ``ee7`` stores (``demo train A_ee7 B_ee7``),
   b. **each arm's** ``ee7`` store alone,
   c. the union in **joint space**: refused, since the arms' joint targets are not the same quantity
      (7 vs 6 joints); the refusal line is recorded, as is the one for the ``ee7`` union on the
      default observations (``obs.joint_pos`` is 7 values on one arm, 6 on the other),
   d. the first arm's **joint** store (the same demonstrations as its ``ee7`` store, ``demo train``'s
      default observations, joint positions included), and its ``ee7`` store on those same
      observations, so that the pair differs in the action alone;

   every ``ee7`` policy reads robot-agnostic observations
   (:data:`demo.training.data.ROBOT_AGNOSTIC_KEYS`: EE pose, gripper, object pose and its offset from
   the EE, all in the scene frame);
3. evaluate (``demo eval``, the same eval seeds for every policy) the union on each arm, each per-arm
   policy on its own arm and, zero-shot, on the other arm (``--robot``, through that arm's IK), and
   the two policies of (d) on their arm.

The target (issue 16): the union within 5 points of each per-arm policy on that arm.
Run with ``demo bench crossrobot``; it writes one JSON (every number and the configuration). Stores
and runs are kept under ``out`` (replaced on every run) for ``demo eval`` and inspection.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
import time
from typing import Any, Callable

import numpy as np

from demo import algorithms
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.convert.convert import ConvertOptions, convert_store
from demo.errors import DemoError
from demo.sim import load_robot, make_env
from demo.sim.robot import BUILTIN_CONFIG
from demo.training.config import for_policy

UR5E = str(Path(__file__).resolve().parent.parent / "sim" / "assets" / "robots" / "robosuite_ur5e.toml")
BUILTIN = "builtin"
TARGET_POINTS = 0.05  # the union may trail a per-arm policy by at most this much success


@dataclass
class CrossRobotConfig:
    out: str = "crossrobot"
    task: str = "pick"
    robots: tuple[str, ...] = (BUILTIN, UR5E)  # robot config TOMLs ("builtin": the built-in arm); the first is the one-arm comparison's
    demos: int = 100  # demonstrations per arm
    episodes: int = 100  # evaluation episodes per policy and arm
    seed: int = 0  # collection, training and evaluation
    steps: int | None = None  # BC optimiser steps (None: demo train's default)
    workers: int = 1  # collection and evaluation processes
    obs_keys: tuple[str, ...] | None = None  # the ee7 policies' observations (None: ROBOT_AGNOSTIC_KEYS)


def _config_path(robot: str) -> str:
    """A robot config TOML's path (``builtin``: the built-in arm's)."""
    return str(BUILTIN_CONFIG) if robot == BUILTIN else robot


def _robot(config_path: str, task: str) -> Any:
    """The arm (a RobotConfig); refuses one whose base body is rotated in the scene: its ``ee7`` actions
    (base frame) and the observations (scene frame) would then be in different frames."""
    robot = load_robot(config_path)
    env = make_env(task, robot=robot)
    try:
        env.reset(0)
        quat = np.array(env.data.xquat[env.model.body(robot.base_body).id])
    finally:
        env.close()
    if not np.allclose(np.abs(quat), [1, 0, 0, 0], atol=1e-9):
        raise DemoError(config_path, f"its base body {robot.base_body!r} is rotated in the scene (quat {quat.round(4).tolist()}): "
                                     "its ee7 actions (base frame) and observations (scene frame) would differ; "
                                     "use an arm whose base is not rotated")
    return robot


def run(c: CrossRobotConfig, log: Callable[[str], None] = print) -> dict[str, Any]:
    from demo.evaluation.evaluate import EvalConfig, evaluate  # deferred: torch stays out of demo --help
    from demo.training.data import ROBOT_AGNOSTIC_KEYS  # deferred: torch stays out of demo --help

    if len(c.robots) != 2:
        raise DemoError("--robot", f"the experiment compares two arms, got {len(c.robots)}")
    if c.demos < 4 or c.episodes < 1:
        raise DemoError("--demos" if c.demos < 4 else "--episodes", "too small (demos >= 4, episodes >= 1)")
    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    configs = [_config_path(r) for r in c.robots]
    arms = [_robot(r, c.task) for r in configs]
    names = [a.name for a in arms]
    if len(set(names)) != len(names):
        raise DemoError("--robot", f"the two arms must have different names, got {names}")
    joint, ee7, collected = {}, {}, {}
    for arm, config_path in zip(arms, configs):
        joint[arm.name], ee7[arm.name] = out / f"{arm.name}.zarr", out / f"{arm.name}_ee7.zarr"
        log(f"[{arm.name}] collecting {c.demos} {c.task} demonstrations")
        result = collect_scripted(CollectConfig(task=c.task, episodes=c.demos, seed=c.seed, robot=config_path),
                                  joint[arm.name], workers=c.workers if c.workers > 1 else 0, overwrite=True)
        log(f"[{arm.name}] converting to ee7")
        converted = convert_store(joint[arm.name], ee7[arm.name], ConvertOptions(to="ee7"), overwrite=True)
        collected[arm.name] = {"robot": config_path, "dof": arm.n_arm, "base_pos": list(arm.base_pos),
                               "expert_success": result.success_rate, "frames": result.frames,
                               "store": str(joint[arm.name]), "ee7_store": str(ee7[arm.name]),
                               "ee7_frames": converted.frames}

    def fit(name: str, data: str | tuple[str, ...], obs_keys: tuple[str, ...] = ()) -> Path:
        run_dir = out / "runs" / name
        algorithms.train("bc", for_policy("bc", data=data, out=str(run_dir), seed=c.seed, steps=c.steps, obs_keys=obs_keys),
                         overwrite=True)
        return run_dir

    def trained(name: str, data: str | tuple[str, ...], obs_keys: tuple[str, ...] = ()) -> Path:
        log(f"training {name}")
        return fit(name, data, obs_keys)

    def refusal(data: tuple[str, ...]) -> str:
        """``demo train`` on a union that must be refused: its one-line error (nothing is written)."""
        try:
            fit("refused", data)
        except DemoError as exc:
            return str(exc)
        raise RuntimeError(f"a union of {data} was expected to be refused")

    first = names[0]
    obs_keys = ROBOT_AGNOSTIC_KEYS if c.obs_keys is None else c.obs_keys
    runs = {"union_ee7": trained("union_ee7", tuple(str(ee7[n]) for n in names), obs_keys)}
    for n in names:
        runs[f"ee7_{n}"] = trained(f"ee7_{n}", str(ee7[n]), obs_keys)
    runs[f"joint_{first}"] = trained(f"joint_{first}", str(joint[first]))
    runs[f"ee7_{first}_joint_obs"] = trained(f"ee7_{first}_joint_obs", str(ee7[first]))  # the joint policy's observations
    refusals = {"union_joint": refusal(tuple(str(joint[n]) for n in names)),
                "union_ee7_default_obs": refusal(tuple(str(ee7[n]) for n in names))}

    plan = [("union_ee7", n) for n in names] + [(f"ee7_{n}", m) for n in names for m in names] + \
        [(f"joint_{first}", first), (f"ee7_{first}_joint_obs", first)]
    config_of = dict(zip(names, configs))
    rows = []
    for policy, arm in plan:
        log(f"evaluating {policy} on {arm} ({c.episodes} episodes)")
        r = evaluate(EvalConfig(run=str(runs[policy]), robot=config_of[arm], episodes=c.episodes, seed=c.seed,
                                workers=c.workers))
        rows.append({"policy": policy, "robot": arm, "trained_on_robot": r["robot_trained_on"],
                     **{k: r[k] for k in ("success_rate", "ci95", "successes", "episodes", "mean_length", "failures")},
                     "run": str(runs[policy])})
        log(f"{policy} on {arm}: {r['successes']}/{r['episodes']}")
    rate = {(row["policy"], row["robot"]): row["success_rate"] for row in rows}
    comparison = {n: {"union": rate[("union_ee7", n)], "per_arm": rate[(f"ee7_{n}", n)],
                      "points": round(100 * (rate[("union_ee7", n)] - rate[(f"ee7_{n}", n)]), 1)} for n in names}
    return {
        "experiment": "crossrobot",
        "config": {**asdict(c), "robots": list(c.robots), "obs_keys": list(obs_keys)},
        "arms": collected,
        "rows": rows,
        "refusals": refusals,
        "union_vs_per_arm": comparison,
        "ee7_vs_joint": {"robot": first, "ee7": rate[(f"ee7_{first}", first)], "joint": rate[(f"joint_{first}", first)],
                         "ee7_on_the_joint_policy_observations": rate[(f"ee7_{first}_joint_obs", first)]},
        "target": f"union within {TARGET_POINTS:.0%} of each per-arm policy on that arm",
        "meets_target": all(v["union"] >= v["per_arm"] - TARGET_POINTS for v in comparison.values()),
        "seconds": time.perf_counter() - started,
    }
