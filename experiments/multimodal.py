"""`demo bench multimodal`: end-effector paths of two policies from the same start states (task ``avoid``).

Any two runs of any registered policy (diffusion, ACT, BC with any ``--head``) trained on ``avoid``.
For each of ``starts`` start states (``demo eval``'s seed stream, :func:`demo.seeds.eval_seeds`),
each policy runs ``samples`` episodes that differ only in the seed of the policy's own sampling
(the diffusion policy's start noise, the GMM head's component, the discrete head's bins, ACT's
latent with ``latent=sample``; an MSE policy, or ACT with its zero latent, is deterministic and
repeats itself). Every
episode is classified by the side on which the end-effector passes the obstacle: ``left`` (+y of
the obstacle centre, base frame) or ``right``, taken where the EE crosses the obstacle's x, or
``none`` when it never gets past it. The PNG draws the paths from above (x forward, y left) per
policy; the JSON has success and mode counts per policy and how many start states saw both modes.

Figure: the first run's success and mode coverage (the CLI's ``--diffusion``, historically);
reference, same run and start states: the second (e.g. MSE-BC). The rollouts are the shared ones (:func:`demo.sim.rollout.rollout` through
:class:`demo.policies.actor.PolicyActor`, torch on one thread), so success here is ``demo eval``'s
success on these start states.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.figures import pyplot, save_figure
from demo.seeds import eval_seeds
from demo.sim.avoid import OBSTACLE_HALF
from demo.sim.rollout import StepCommand, rollout


def classify(ee: np.ndarray, obstacle: np.ndarray) -> str:
    """Side on which the path ``ee [T, 3]`` passes ``obstacle [3]`` (base frame)."""
    past = np.flatnonzero(ee[:, 0] >= obstacle[0])
    if len(past) == 0:
        return "none"
    return "left" if ee[past[0], 1] > obstacle[1] else "right"


def rollouts(run: str, starts: int, samples: int, seed: int, execute: int | None = None) -> dict[str, Any]:
    from demo.evaluation.evaluate import (  # deferred: torch stays out of demo --help
        execution_for, make_actor, make_eval_env, resolve_target, single_thread)
    from demo.policies.checkpoint import load_bundle  # deferred: torch stays out of demo --help

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
    return {"run": run, "algo": bundle.algo, "policy": policy_label(bundle), "execute": actor.execution.execute,
            "episodes": episodes}


def policy_label(bundle: Any) -> str:
    """The algorithm, and BC's head where it is not the default (``bc gmm``)."""
    head = getattr(bundle.policy.config, "head", "mse")
    return bundle.algo if head == "mse" else f"{bundle.algo} {head}"


def summarize(result: dict[str, Any], starts: int) -> dict[str, Any]:
    eps = result["episodes"]
    modes = {m: sum(e["mode"] == m for e in eps) for m in ("left", "right", "none")}
    both = sum(
        1 for i in range(starts) if {e["mode"] for e in eps if e["start"] == i} >= {"left", "right"}
    )
    return {
        "run": result["run"],
        "algo": result["algo"],
        "policy": result["policy"],
        "execute": result["execute"],
        "episodes": len(eps),
        "success_rate": float(np.mean([e["success"] for e in eps])) if eps else 0.0,
        "modes": modes,
        "successful_modes": {m: sum(e["mode"] == m and e["success"] for e in eps) for m in ("left", "right")},
        "starts_with_both_modes": both,
    }


def plot(results: list[dict[str, Any]], summaries: list[dict[str, Any]], path: str | Path, starts_shown: int = 5) -> Path:
    """One row per policy, one column per start state (the first ``starts_shown``, not picked): every
    sampled path from that start, top view, relative to the obstacle, coloured by the side it passes."""
    plt = pyplot()
    from matplotlib.lines import Line2D  # deferred: heavy dependency (matplotlib), for the figure alone
    from matplotlib.patches import Rectangle  # deferred: heavy dependency (matplotlib), for the figure alone

    side_color = {"left": "tab:blue", "right": "tab:orange", "none": "tab:red"}
    cols = min(starts_shown, 1 + max(e["start"] for e in results[0]["episodes"]))
    fig, axes = plt.subplots(len(results), cols, figsize=(2.6 * cols, 2.9 * len(results)), squeeze=False,
                             sharex=True, sharey=True)
    hx, hy = OBSTACLE_HALF[:2]
    for row, (res, summ) in enumerate(zip(results, summaries)):
        for col in range(cols):
            ax = axes[row, col]
            eps = [e for e in res["episodes"] if e["start"] == col]
            for e in eps:
                xy = e["ee_xy"] - e["obstacle"][:2]
                ax.plot(xy[:, 0], xy[:, 1], color=side_color[e["mode"]], lw=1.4, alpha=0.8, ls="-" if e["success"] else "--")
            if eps:
                ax.plot(*(eps[0]["ee_xy"][0] - eps[0]["obstacle"][:2]), "ko", ms=4)
                ax.plot(*(eps[0]["goal"][:2] - eps[0]["obstacle"][:2]), "g*", ms=10)
                ax.set_title(f"start {col}: " + " ".join(sorted(e["mode"][0].upper() for e in eps)), fontsize=8)
            ax.add_patch(Rectangle((-hx, -hy), 2 * hx, 2 * hy, color="0.45", alpha=0.8))
            ax.set_xlim(-0.3, 0.3)
            ax.set_ylim(-0.3, 0.3)
            ax.set_aspect("equal")
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=7)
        m = summ["modes"]
        axes[row, 0].set_ylabel(
            f"{summ['policy']} (execute {summ['execute']})\nsuccess {summ['success_rate']:.0%}, L {m['left']} / R {m['right']}"
            f" / none {m['none']}\nboth sides from one start: {summ['starts_with_both_modes']}\ny - obstacle y (m)",
            fontsize=8,
        )
    for ax in axes[-1]:
        ax.set_xlabel("x - obstacle x (m)", fontsize=8)
    legend = [Line2D([], [], color=c, label=f"passes {k}") for k, c in side_color.items()]
    legend += [Line2D([], [], color="k", ls="--", label="failed")]
    fig.legend(handles=legend, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(
        f"avoid: end-effector paths (top view) sampled from the same start states, "
        f"{sum(e['start'] == 0 for e in results[0]['episodes'])} per start and policy;"
        " o start, * goal, grey: obstacle",
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return save_figure(fig, path)


def run(figure: str, reference: str, starts: int = 20, samples: int = 3, seed: int = 0, png: str | None = None,
        execute: int | None = None, reference_execute: int | None = None) -> dict[str, Any]:
    """Both runs (any policies) from the same start states; ``execute``/``reference_execute`` override
    each run's actions per chunk (default: the run's own)."""
    if starts < 1 or samples < 1:
        raise DemoError("--starts/--samples", "must be at least 1")
    results = [rollouts(figure, starts, samples, seed, execute), rollouts(reference, starts, samples, seed, reference_execute)]
    summaries = [summarize(r, starts) for r in results]
    out: dict[str, Any] = {
        "benchmark": "multimodal",
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
