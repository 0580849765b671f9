"""AggreVaTe (Ross & Bagnell 2014): learning from the expert's cost-to-go.

``demo train DATA --algo aggrevate --task T --rounds R --episodes-per-round K [--algo-opt states=10 ...]``
runs DAgger's loop (:func:`demo.imitation.dagger.train_dagger`) with this file's :class:`AggreVaTe`
rounds. DAgger labels a visited state with the expert's action; AggreVaTe labels it with the action
whose *cost-to-go under the expert* is lowest: at ``states`` steps per rollout, drawn uniformly over
the horizon, the simulator state is saved and each of ``candidates`` actions is tried from it (the
expert's, the learner's, and the learner's plus Gaussian noise of ``sigma`` rad on the arm joint
targets), followed by the expert to the end (:func:`cost_to_go`); the state is then restored and the
roll-in continues. The label is the cheapest candidate (ties go to the expert's action, listed
first). This is the cost-sensitive reduction of AggreVaTe for continuous actions by argmin over
sampled candidates; AggreVaTeD's gradient of the cost-to-go through the policy is not implemented.

The cost: ``Q(s, a)`` = control steps from ``s`` until the task's success predicate first holds when
``a`` is executed at ``s`` and the expert acts after it; if it never holds before the horizon, the
steps left to the horizon plus ``failure_cost`` (default: one horizon). With a near-optimal expert
most labels are the expert's own action, so AggreVaTe spends far more simulator steps per label than
DAgger: each label costs ``candidates`` expert rollouts to the end, counted per round as
``sim_steps`` (control steps of 25 physics steps each), against the roll-in's own steps.

The roll-in is DAgger's: the learner drives, or the expert with probability ``beta`` (``--beta``).
Labels counted: one per sampled state (``info.labelled``); the roll-in's other frames are stored
unlabelled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from demo.sim.rollout import StepCommand, rollout
from demo.imitation.dagger import Family, episode_record


def cost_to_go(env: Any, state: np.ndarray, action: np.ndarray | None, seed: int, failure_cost: float | None = None,
               ) -> tuple[float, int]:
    """``Q(state, action)`` (module docstring) and the control steps it took to measure.

    Restores ``state`` (``env.get_state()``), executes ``action`` (None: the expert's own), then the
    task's expert (a fresh one, its per-episode choices drawn as the roll-in expert's: rng ``[seed, 2]``)
    until success first holds or the horizon. Leaves the environment wherever that ended."""
    env.set_state(state)
    remaining = env.horizon - env.steps
    if remaining <= 0:
        return (0.0 if env.success() else float(failure_cost if failure_cost is not None else env.horizon)), 0
    expert = env.expert(rng=np.random.default_rng([seed, 2]))

    def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
        a = action if (t == 0 and action is not None) else np.asarray(expert.act(env), dtype=np.float32)
        return StepCommand(executed=a, label=a)

    episode = rollout(env, seed, act, max_steps=remaining, hold_success_s=0.0, record=False, reset=False)
    if episode.first_success_step is not None:
        return float(episode.first_success_step), episode.length
    return float(remaining + (failure_cost if failure_cost is not None else env.horizon)), episode.length


@dataclass
class AggrevateEpisodes:
    """One AggreVaTe roll-in with cost-to-go labels at sampled steps (module docstring)."""

    beta: float
    n_arm: int
    states: int
    candidates: int
    sigma: float
    failure_cost: float | None

    def __call__(self, env: Any, actor: Any, seed: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        env.reset(seed)
        actor.reset(seed, env)
        expert = env.expert(rng=np.random.default_rng([seed, 2]))
        mix, rng = np.random.default_rng([seed, 3]), np.random.default_rng([seed, 4])
        chosen = set(rng.choice(env.horizon, size=min(self.states, env.horizon), replace=False).tolist())
        labelled: list[bool] = []
        in_control: list[bool] = []
        spent = [0, 0]  # control steps of the cost rollouts; labels where a candidate beat the expert's action

        def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
            own = np.asarray(expert.act(env), dtype=np.float32)
            mine = np.asarray(actor.act(frame), dtype=np.float32)
            use_expert = bool(mix.random() < self.beta) if self.beta > 0 else False
            label = own
            if t in chosen:
                candidates = [own, mine] + [self._explore(mine, rng) for _ in range(self.candidates - 2)]
                candidates = candidates[: self.candidates]
                costs = [0.0]  # one candidate: the expert's, nothing to compare
                if len(candidates) > 1:
                    state, costs = env.get_state(), []
                    for a in candidates:
                        cost, steps = cost_to_go(env, state, a, seed, self.failure_cost)
                        costs.append(cost)
                        spent[0] += steps
                    env.set_state(state)
                best = int(np.argmin(costs))  # the first of equals: the expert's action
                spent[1] += int(best != 0)
                label = candidates[best]
            labelled.append(t in chosen)
            in_control.append(use_expert)
            return StepCommand(executed=own if use_expert else mine, label=label,
                               ee_target=np.asarray(expert.ee_target, np.float32))

        episode = rollout(env, seed, act, reset=False)
        data, info = episode_record(episode, seed, labelled, in_control, self.beta)
        info.update(cost_steps=spent[0], better_than_expert=spent[1], rollin_steps=episode.length)
        return data, info

    def _explore(self, mine: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        a = mine.copy()
        a[: self.n_arm] += rng.normal(0.0, self.sigma, self.n_arm).astype(np.float32)
        return a


@dataclass
class AggreVaTe(Family):
    """AggreVaTe's rounds (module docstring). ``states``: sampled steps per rollout; ``candidates``
    (>= 1): actions tried at each (the expert's, then the learner's, then the learner's + noise);
    ``sigma``: that noise's std (rad); ``failure_cost``: control steps a failure adds (None: one horizon)."""

    name: str = "aggrevate"
    OPTIONS: ClassVar[tuple[str, ...]] = ("states", "candidates", "sigma", "failure_cost")
    CHUNK_LABELS: ClassVar[bool] = False  # its own labelling: single-step labels
    FOREIGN: ClassVar[bool] = False  # needs the simulator's state and the task's own expert
    states: int = 10
    candidates: int = 3
    sigma: float = 0.05
    failure_cost: float | None = None

    def episodes(self, run: Any, store: Any, env: Any, r: int, beta: float, gate: float | None) -> AggrevateEpisodes:
        return AggrevateEpisodes(beta, len(env.robot.arm_joints), self.states, self.candidates, self.sigma,
                                 self.failure_cost)

    def round_entry(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        return {"sim_steps": int(sum(int(i.get("cost_steps", 0)) for i in infos)),
                "rollin_steps": int(sum(int(i.get("rollin_steps", 0)) for i in infos)),
                "labels_better_than_expert": int(sum(int(i.get("better_than_expert", 0)) for i in infos))}

    def to_json(self) -> dict[str, Any]:
        return {"cost": "control steps until success first holds; failure: steps left + failure_cost",
                "states": self.states, "candidates": self.candidates, "sigma": self.sigma,
                "failure_cost": self.failure_cost}
