"""Linear-reward inverse RL: maximum-entropy IRL (Ziebart et al. 2008) and apprenticeship learning
by feature-expectation matching (Abbeel & Ng 2004), over the task features of :mod:`demo.rl.rewards`.

The reward is ``r(s') = w . phi(s')`` with ``phi`` the documented features of the task's dense reward
(``reach``: position error [m], rotation error [rad], success [0/1]), so the recovered ``w`` compares
with the true weights directly (up to scale, which no IRL method can recover: only the direction
``w / |w|`` is reported against the truth's).

**Feature expectations** ``mu = E[sum_t gamma^t phi(s_{t+1})]`` over episodes of the task's horizon
``H``: a demonstration ends once success has held 0.5 s, settled, so its last state's features are
repeated up to ``H`` (the expert would stay); an RL episode runs to ``H`` (or ends failed, then
padded the same way). ``mu_E`` comes from the demonstrations, ``mu_pi`` from the episodes of the
last PPO iteration.

Both methods alternate a reward update with ``inner_iterations`` PPO iterations on the current
reward (the policy is warm-started, not retrained from scratch: the sample-based form of each
algorithm's inner "solve the MDP" step, which a CPU budget cannot afford to run to convergence):

- **maxent**: gradient ascent on the demonstrations' log-likelihood under the MaxEnt model, whose
  gradient for a linear reward is ``mu_E - mu_pi``; Adam with step ``lr`` and an L2 term ``l2 w``.
- **apprenticeship** (the projection method): ``mu_bar`` starts at the first policy's ``mu``;
  after each solve, ``mu_bar`` moves to the projection of ``mu_E`` onto the line through ``mu_bar``
  and the new ``mu_pi``; ``w = mu_E - mu_bar`` and the margin ``t = |w|`` (which falls as the policy
  matches the expert's features). The policy kept is the last one (not the paper's mixture).

:func:`maxent_irl` and :func:`apprenticeship` take the solver as a callback (weights -> feature
expectations), so they run as well on a small MDP solved exactly (the tests).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.figures import pyplot, save_figure
from demo.progress import Progress
from demo.rl.config import LinearIRLConfig
from demo.rl.ppo import RLRun, Rollout
from demo.rl.rewards import pearson

WEIGHTS_PLOT = "weights.png"
Solver = Callable[[np.ndarray], np.ndarray]  # reward weights -> feature expectations of the policy trained on them


# ====================================================================================== feature expectations
def discounted_sums(episodes: Sequence[np.ndarray], horizon: int, gamma: float) -> np.ndarray:
    """Mean over episodes (``[L_i, F]`` features each) of ``sum_{t<H} gamma^t phi_t``, each episode's
    last row repeated up to ``horizon`` (module docstring); ``[F]``."""
    discount = gamma ** np.arange(horizon)
    sums = []
    for phi in episodes:
        phi = np.asarray(phi, np.float64)[:horizon]
        padded = np.concatenate([phi, np.repeat(phi[-1:], horizon - len(phi), axis=0)])
        sums.append(discount @ padded)
    return np.mean(sums, axis=0)


def rollout_episodes(roll: Rollout) -> list[np.ndarray]:
    """The features of every episode that both starts and ends within the rollout."""
    out = []
    for i in range(roll.features.shape[1]):
        start = None
        for t in range(len(roll.features)):
            if roll.starts[t, i]:
                start = t
            if roll.dones[t, i] and start is not None:
                out.append(roll.features[start:t + 1, i])
                start = None
    return out


# ====================================================================================== the two methods
class Adam:
    """Adam ascent on a numpy vector (Kingma & Ba 2015), for the reward weights."""

    def __init__(self, lr: float, b1: float = 0.9, b2: float = 0.999):
        self.lr, self.b1, self.b2, self.t = lr, b1, b2, 0
        self.m: np.ndarray | float = 0.0
        self.v: np.ndarray | float = 0.0

    def step(self, w: np.ndarray, grad: np.ndarray) -> np.ndarray:
        self.t += 1
        self.m = self.b1 * self.m + (1 - self.b1) * grad
        self.v = self.b2 * self.v + (1 - self.b2) * grad**2
        m, v = self.m / (1 - self.b1**self.t), self.v / (1 - self.b2**self.t)
        return w + self.lr * m / (np.sqrt(v) + 1e-8)


def maxent_irl(mu_expert: np.ndarray, solve: Solver, rounds: int, lr: float, l2: float = 0.0,
               w0: np.ndarray | None = None) -> list[dict[str, Any]]:
    """``rounds`` ascent steps ``w += Adam(mu_E - mu_pi(w) - l2 w)``; per round the ``w`` solved for, its
    ``mu_pi``, the gap ``|mu_E - mu_pi|`` and ``w_next`` (the last round's is the estimate)."""
    w = np.zeros_like(mu_expert, dtype=np.float64) if w0 is None else np.asarray(w0, np.float64)
    adam, history = Adam(lr), []
    for r in range(rounds):
        mu = solve(w)
        entry = {"round": r, "w": w.tolist(), "mu": np.asarray(mu).tolist(), "gap": float(np.linalg.norm(mu_expert - mu))}
        w = adam.step(w, mu_expert - mu - l2 * w)
        history.append({**entry, "w_next": w.tolist()})
    return history


def apprenticeship(mu_expert: np.ndarray, solve: Solver, rounds: int, w0: np.ndarray | None = None
                   ) -> list[dict[str, Any]]:
    """The projection method: ``rounds`` solves; per round the ``w`` solved for, its ``mu_pi``, ``mu_bar``, the
    margin ``t = |mu_E - mu_bar|`` and ``w_next = mu_E - mu_bar`` (the last round's is the estimate)."""
    mu_bar = np.asarray(solve(np.zeros_like(mu_expert) if w0 is None else w0), np.float64)
    history = [{"round": 0, "w": np.zeros_like(mu_bar).tolist() if w0 is None else np.asarray(w0).tolist(),
                "mu": mu_bar.tolist(), "mu_bar": mu_bar.tolist(), "t": float(np.linalg.norm(mu_expert - mu_bar)),
                "w_next": (mu_expert - mu_bar).tolist()}]
    for r in range(1, rounds):
        w = mu_expert - mu_bar
        mu = np.asarray(solve(w), np.float64)
        d = mu - mu_bar
        if d @ d > 1e-12:
            mu_bar = mu_bar + (d @ (mu_expert - mu_bar)) / (d @ d) * d
        history.append({"round": r, "w": w.tolist(), "mu": mu.tolist(), "mu_bar": mu_bar.tolist(),
                        "t": float(np.linalg.norm(mu_expert - mu_bar)), "w_next": (mu_expert - mu_bar).tolist()})
    return history


def unit(w: Sequence[float]) -> np.ndarray:
    w = np.asarray(w, np.float64)
    n = np.linalg.norm(w)
    return w / n if n > 0 else w


# ====================================================================================== on the tasks
def train(config: LinearIRLConfig, *, progress: Progress | None = None, overwrite: bool = False,
          command: str | None = None) -> dict[str, Any]:
    """Linear IRL on the demonstrations ``config.data`` into ``config.rl.out``; returns the summary with
    the recovered weights (raw and unit-norm) beside the true ones."""
    config.check()
    c = config.rl
    with RLRun(c, name=config.method, progress=progress, overwrite=overwrite, command=command) as rl:
        expert = rl.demonstrations(config.data, config.demos)
        horizon = rl.pool.horizon
        mu_expert = discounted_sums([expert.features[expert.episode == e] for e in range(expert.episodes)],
                                    horizon, c.gamma)
        rl.record["linear_irl"] = {**config.to_json(), "features": list(rl.reward.names),
                                   "units": list(rl.reward.units), "mu_expert": mu_expert.tolist()}
        rl.open()
        last: dict[str, Any] = {}

        def solve(w: np.ndarray) -> np.ndarray:
            for _ in range(config.inner_iterations):
                if rl.iteration >= c.iterations:
                    break
                last["roll"] = rl.iterate(lambda r: r.features @ w)
                rl.metrics["iterations"][-1]["w"] = w.tolist()
            episodes = rollout_episodes(last["roll"])
            if not episodes:
                raise DemoError("--rollout", "no episode started and ended within an iteration: make the "
                                              f"steps per environment and iteration at least the horizon ({horizon})")
            return discounted_sums(episodes, horizon, c.gamma)

        rounds = max(1, -(-c.iterations // config.inner_iterations))
        if config.method == "maxent":
            history = maxent_irl(mu_expert, solve, rounds, config.lr, config.l2)
        else:
            history = apprenticeship(mu_expert, solve, rounds)
        w = np.asarray(history[-1]["w_next"])
        true = np.asarray(rl.reward.weights)
        roll = last["roll"]
        result = {"features": list(rl.reward.names), "units": list(rl.reward.units), "weights": w.tolist(),
                  "weights_unit": unit(w).tolist(), "true_weights": true.tolist(), "true_unit": unit(true).tolist(),
                  "cosine_to_true": float(unit(w) @ unit(true)),
                  "reward_corr": pearson(roll.features @ w, roll.task_reward), "mu_expert": mu_expert.tolist()}
        rl.metrics["linear_irl"] = {"history": history, **result}
        rl.record["reward_weights"] = result
        plot_weights(history, result, Path(c.out) / WEIGHTS_PLOT, title=f"{config.method} on {c.task}")
        return rl.finish(**result, demos=expert.episodes)


def plot_weights(history: Sequence[dict[str, Any]], result: dict[str, Any], path: Path, title: str = "") -> Path:
    """Recovered unit-norm weights beside the true ones (bars) and their course over the rounds."""

    plt = pyplot()
    names = [f"{n} [{u}]" for n, u in zip(result["features"], result["units"])]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(names))
    ax.bar(x - 0.2, result["true_unit"], 0.4, label="true (dense task reward)")
    ax.bar(x + 0.2, result["weights_unit"], 0.4, label="recovered")
    ax.set_xticks(x, names)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_ylabel("weight / |w|")
    ax.set_title(f"cosine {result['cosine_to_true']:.2f}, reward correlation {result['reward_corr']:.2f}", fontsize=9)
    ax.legend(fontsize=8)
    ws = np.array([unit(h["w_next"]) for h in history])
    for j, name in enumerate(names):
        ax2.plot(np.arange(len(ws)), ws[:, j], "o-", ms=3, label=name)
    ax2.set_xlabel("reward update")
    ax2.set_ylabel("weight / |w|")
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
