"""`demo bench samplers`: milliseconds per action chunk (batch 1, CPU) of the three ways a chunk is made.

- ``mse``: BC's MLP, one forward pass (:mod:`demo.policies.mlp`);
- ``diffusion``: the diffusion policy's DDIM at its default steps (8), conditioning cached, traced
  denoiser (:mod:`demo.policies.diffusion`): the reference of the ratios;
- ``flow-K``: flow matching with K Euler steps (:mod:`demo.policies.flow`), K in ``steps`` (1, 4, 10).

Diffusion and flow use the same residual-MLP network (width 512, depth 3), so the difference is the
sampler's. Networks are freshly initialised at the sizes of ``avoid`` (observation 29 values, 2 frames;
action 8 values; chunk 16): latency does not depend on the weights' values. The samplers are timed in
turn, round after round (:func:`demo.bench.infer.time_interleaved`), so every figure sees the same
machine; torch runs on ``threads`` threads (``demo eval`` uses 1).

With ``runs`` (``flow=RUN``, ``diffusion=RUN``, ``bc=RUN`` trained on the same store), each run's success
on the same ``demo eval`` episodes, flow's at every K.
"""

from __future__ import annotations

from typing import Any

import torch

from demo.bench.common import machine
from demo.bench.infer import success, time_interleaved
from demo.errors import DemoError
from demo.policies.checkpoint import load_bundle
from demo.policies.policy import PolicySpec, build_policy

STEPS = (1, 4, 10)  # Euler steps timed for flow matching (pi0 integrates in 10)


def run(steps: tuple[int, ...] = STEPS, obs_dim: int = 29, action_dim: int = 8, n_obs: int = 2, horizon: int = 16,
        seconds: float = 10.0, threads: int = 1, runs: dict[str, str] | None = None, episodes: int = 100,
        seed: int = 0) -> dict[str, Any]:
    """Latency per chunk of each sampler (module docstring) and, with ``runs``, each run's success."""
    if not steps or min(steps) < 1:
        raise DemoError("--steps", f"Euler steps must be positive, got {list(steps)}")
    unknown = sorted(set(runs or {}) - {"bc", "diffusion", "flow"})
    if unknown:
        raise DemoError("--run", f"names a run as bc=RUN, diffusion=RUN or flow=RUN, not {', '.join(unknown)}")
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        torch.manual_seed(0)
        spec = PolicySpec(obs_dim, action_dim, n_obs, horizon)
        samplers: dict[str, Any] = {"mse": build_policy("bc", spec).eval(), "diffusion": build_policy("diffusion", spec).eval()}
        for k in steps:
            samplers[f"flow-{k}"] = build_policy("flow", spec, {"inference_steps": k}).eval()
        obs = torch.zeros(1, n_obs, obs_dim)
        timed = time_interleaved(samplers, obs, seconds)
    finally:
        torch.set_num_threads(previous)
    reference = timed["diffusion"]["ms_median"]
    result: dict[str, Any] = {
        "bench": "samplers",
        "ms_per_chunk": {name: t["ms_median"] for name, t in timed.items()},
        "reference": "diffusion (DDIM, 8 steps)",
        "reference_ms_per_chunk": reference,
        "ratio_to_reference": {name: t["ms_median"] / reference for name, t in timed.items()},
        "timing": timed,
        "config": {"steps": list(steps), "obs_dim": obs_dim, "action_dim": action_dim, "n_obs": n_obs,
                   "horizon": horizon, "seconds": seconds, "threads": threads},
        "machine": machine(),
    }
    if runs:
        result["success"] = run_success(runs, steps, episodes, seed)
    return result


def run_success(runs: dict[str, str], steps: tuple[int, ...], episodes: int, seed: int) -> dict[str, Any]:
    """Each run's success on the same evaluation episodes (flow's at every K of ``steps``)."""
    out: dict[str, Any] = {}
    for name, path in runs.items():
        bundle = load_bundle(path)
        if bundle.algo != name:
            raise DemoError(path, f"is a {bundle.algo!r} run, given as {name}=")
        if name != "flow":
            out[name] = success(bundle, episodes, seed)
            continue
        for k in steps:
            bundle.policy.config.inference_steps = k
            out[f"flow-{k}"] = success(bundle, episodes, seed)
    return out
