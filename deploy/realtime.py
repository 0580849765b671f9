"""The whole loop tested here: ``demo serve``'s server, the robot-side loop and the simulator as a
stand-in robot in real time, with injected inference and network delays (``demo bench realtime``)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.deploy.arm_model import ArmModel
from demo.deploy.controller import ChunkMerger, ChunkRequester, ControlConfig, Safety, run_episode
from demo.deploy.server import PolicyServer, ServerConfig
from demo.deploy.sim_robot import SimRobot
from demo.evaluation.evaluate import wilson_interval
from demo.progress import Progress, Tick, or_silent
from demo.seeds import eval_seeds


@dataclass
class RealtimeConfig:
    run: str
    episodes: int = 20
    seed: int = 0
    inference_delay_s: float = 0.0  # added by the server to every answer
    network_s: float = 0.0  # each way
    control: ControlConfig | None = None


def run_realtime(config: RealtimeConfig, progress: Progress | None = None) -> dict[str, Any]:
    """``episodes`` real-time episodes of the run's task on its evaluation seeds; success (95% interval),
    stalls, clipped commands, inference round trips."""
    control = config.control or ControlConfig()
    server = PolicyServer(ServerConfig(config.run, port=0, delay_s=config.inference_delay_s)).start()
    trained = server.bundle.run["task"]  # run.json's task section (checked when the bundle loaded)
    task, options = trained["name"], dict(trained.get("options") or {})
    robot = SimRobot(task, rate_hz=control.rate_hz, **options)
    requester = ChunkRequester(server.url, ChunkMerger(control.ensemble), control.network_s)
    tell = or_silent(progress)
    reports = []
    start = time.perf_counter()
    try:
        arm = ArmModel(task, options)  # the robot side's own model of the arm: limits and kinematics
        safety = Safety(arm.limits, control.max_joint_step, arm.table_workspace(), arm.ee_position)
        for i, seed in enumerate(eval_seeds(config.seed, config.episodes)):
            reports.append(run_episode(robot, requester, safety, control, int(seed)))
            ok = sum(r.success for r in reports)
            tell(Tick("realtime", i + 1, config.episodes, {"success": f"{ok}/{i + 1}"}))
    finally:
        requester.close()
        robot.close()
        server.close()
    successes = sum(r.success for r in reports)
    latency = np.concatenate([r.latency_ms for r in reports]) if reports else np.zeros(0)
    return {
        "run": config.run, "task": task, "episodes": len(reports), "successes": successes,
        "success_rate": successes / max(len(reports), 1), "ci95": list(wilson_interval(successes, len(reports))),
        "inference_delay_ms": 1000 * config.inference_delay_s, "network_ms_each_way": 1000 * control.network_s,
        "round_trip_ms": {"median": float(np.median(latency)) if len(latency) else None,
                          "p95": float(np.percentile(latency, 95)) if len(latency) else None},
        "stall_steps": sum(r.stalls for r in reports), "steps": sum(r.steps for r in reports),
        "clipped_commands": sum(r.clipped for r in reports), "outside_workspace": sum(r.outside for r in reports),
        "loop_overruns": sum(r.overruns for r in reports),
        "seconds": time.perf_counter() - start,
    }
