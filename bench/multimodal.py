"""`demo bench modes`: end-effector paths of two policies from the same start states (task ``avoid``).

For each of ``starts`` start states (``demo eval``'s seed stream, :func:`demo.train.seeds.eval_seeds`),
each policy runs ``samples`` episodes that differ only in the seed of the policy's own sampling
(the diffusion policy's start noise; an MSE policy is deterministic and repeats itself). Every
episode is classified by the side on which the end-effector passes the obstacle: ``left`` (+y of
the obstacle centre, base frame) or ``right``, taken where the EE crosses the obstacle's x, or
``none`` when it never gets past it. The PNG draws the paths from above (x forward, y left) per
policy; the JSON has success and mode counts per policy and how many start states saw both modes.

Figure: the diffusion run's success and mode coverage; reference, same run and start states: the
MSE-BC run. The rollouts are the shared ones (:func:`demo.collect.rollout.rollout` through
:class:`demo.train.actor.PolicyActor`, torch on one thread), so success here is ``demo eval``'s
success on these start states.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError

OBSTACLE_HALF_XY = (0.03, 0.07)  # m, the avoid task's obstacle (demo.sim.avoid.OBSTACLE_HALF)


def classify(ee: np.ndarray, obstacle: np.ndarray) -> str:
    """Side on which the path ``ee [T, 3]`` passes ``obstacle [3]`` (base frame)."""
    past = np.flatnonzero(ee[:, 0] >= obstacle[0])
    if len(past) == 0:
        return "none"
    return "left" if ee[past[0], 1] > obstacle[1] else "right"


def rollouts(run: str, starts: int, samples: int, seed: int, execute: int | None = None) -> dict[str, Any]:
    from demo.collect.rollout import StepCommand, rollout
    from demo.train.checkpoint import load_bundle
    from demo.train.evaluate import execution_for, make_actor, make_eval_env, resolve_target, single_thread
    from demo.train.seeds import eval_seeds

    bundle = load_bundle(run)
    task, options, robot = resolve_target(bundle, None, None, None)
    if task != "avoid":
        raise DemoError(run, f"was trained on {task!r}; the path comparison is for 'avoid'")
    env = make_eval_env(bundle, task, options, robot)
    episodes: list[dict[str, Any]] = []
    try:
        actor = make_actor(bundle, env, execution_for(bundle, execute, None))
        with single_thread():
            for i, start in enumerate(eval_seeds(seed, starts)):
                for k in range(samples):
                    env.reset(start)
                    actor.reset(start + 7919 * k, env)  # same start state, another sampling seed

                    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
                        a = actor.act(frame)
                        return StepCommand(executed=a, label=a)

                    ep = rollout(env, start, act, reset=False)
                    ee = ep.data["obs.ee_pos"].astype(float)
                    obstacle = ep.data["obs.obstacle_pos"][0].astype(float)
                    episodes.append({
                        "start": i, "seed": int(start), "sample": k, "success": bool(ep.success),
                        "mode": classify(ee, obstacle), "length": ep.length,
                        "ee_xy": ee[:, :2], "obstacle": obstacle, "goal": ep.data["obs.goal_pos"][0].astype(float),
                    })
    finally:
        env.close()
    return {"run": run, "algo": bundle.algo, "execute": actor.execution.execute, "episodes": episodes}


def summarize(result: dict[str, Any], starts: int) -> dict[str, Any]:
    eps = result["episodes"]
    modes = {m: sum(e["mode"] == m for e in eps) for m in ("left", "right", "none")}
    both = sum(
        1 for i in range(starts) if {e["mode"] for e in eps if e["start"] == i} >= {"left", "right"}
    )
    return {
        "run": result["run"],
        "algo": result["algo"],
        "execute": result["execute"],
        "episodes": len(eps),
        "success_rate": float(np.mean([e["success"] for e in eps])) if eps else 0.0,
        "modes": modes,
        "successful_modes": {m: sum(e["mode"] == m and e["success"] for e in eps) for m in ("left", "right")},
        "starts_with_both_modes": both,
    }


def plot(results: list[dict[str, Any]], summaries: list[dict[str, Any]], path: str | Path, starts_shown: int = 6) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    colors = plt.get_cmap("tab10")
    fig, axes = plt.subplots(1, len(results), figsize=(5.2 * len(results), 4.8), squeeze=False)
    for ax, res, summ in zip(axes[0], results, summaries):
        for e in res["episodes"]:
            if e["start"] >= starts_shown:
                continue
            # paths relative to the obstacle centre, so start states with shifted obstacles overlay
            xy = e["ee_xy"] - e["obstacle"][:2]
            c = colors(e["start"] % 10)
            ax.plot(xy[:, 0], xy[:, 1], color=c, lw=1.3, alpha=0.85, ls="-" if e["success"] else "--")
            ax.plot(*xy[0], "o", color=c, ms=4)
            g = e["goal"][:2] - e["obstacle"][:2]
            ax.plot(*g, "*", color=c, ms=9)
        hx, hy = OBSTACLE_HALF_XY
        ax.add_patch(Rectangle((-hx, -hy), 2 * hx, 2 * hy, color="0.45", alpha=0.8))
        m = summ["modes"]
        ax.set_title(
            f"{summ['algo']} (execute {summ['execute']}): success {summ['success_rate']:.0%}, left {m['left']} / right {m['right']}"
            f" / none {m['none']}\nboth modes from the same start: {summ['starts_with_both_modes']} starts",
            fontsize=9,
        )
        ax.set_xlabel("x - obstacle x (m, forward)")
        # the task's workspace; a diverging policy's excursions leave the frame
        ax.set_xlim(-0.3, 0.32)
        ax.set_ylim(-0.3, 0.3)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("y - obstacle y (m, left)")
    fig.suptitle(
        f"avoid: EE paths from the same {starts_shown} start states (colour; o start, * goal), top view, "
        "relative to the obstacle; dashed = failed",
        fontsize=9,
    )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run(diffusion: str, reference: str, starts: int = 20, samples: int = 3, seed: int = 0, png: str | None = None,
        execute: int | None = None, reference_execute: int | None = None) -> dict[str, Any]:
    """Both runs from the same start states; ``execute``/``reference_execute`` override each run's
    actions per chunk (default: the run's own)."""
    if starts < 1 or samples < 1:
        raise DemoError("--starts/--samples", "must be at least 1")
    results = [rollouts(diffusion, starts, samples, seed, execute), rollouts(reference, starts, samples, seed, reference_execute)]
    summaries = [summarize(r, starts) for r in results]
    out: dict[str, Any] = {
        "benchmark": "modes",
        "task": "avoid",
        "starts": starts,
        "samples_per_start": samples,
        "seed": seed,
        "seed_rule": "start i = eval_seeds(seed)[i] (demo eval's stream); sample k reseeds the policy with start + 7919 k",
        "figure": summaries[0],
        "reference": summaries[1],
    }
    if png:
        out["png"] = str(plot(results, summaries, png))
    return out
