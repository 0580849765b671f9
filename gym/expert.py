"""The task's scripted expert behind a Gymnasium env, answering in the env's action representation: for
the env's own state (:class:`GymExpert`), or from observations alone, row by row of a batch
(:class:`ObservationExpert`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from demo.errors import DemoError
from demo.sim.task import Expert

if TYPE_CHECKING:
    from demo.gym.env import DemoEnv


class GymExpert:
    """What :meth:`demo.gym.env.DemoEnv.expert` returns: ``act(obs)`` is the expert's action for the
    env's current state, in the env's action representation (a float32 array in ``env.action_space``'s
    layout), ready for ``env.step``.

    The expert is a state-feedback policy (:class:`demo.sim.task.Expert`): it reads the simulator
    state, which is the state ``obs`` was observed in, so ``obs`` is accepted (for the usual
    ``policy(obs)`` interface) and not read. Ask it in any state the env reaches (DAgger labels).
    Delta representations (``ee7``, ``ee_delta``, ``joint_vel``) are relative to the env's last
    executed command, so the answer is the step from whatever was executed last to the expert's pose.
    """

    def __init__(self, env: "DemoEnv", expert: Expert):
        self.env = env
        self.expert = expert  # the simulator-level expert (answers joint_pos)

    @property
    def mode(self) -> str | None:
        """The demonstration mode it follows (avoid: ``"left"`` / ``"right"``), else None."""
        return self.expert.mode

    def act(self, obs: Any = None) -> np.ndarray:
        return self.env.normalized(self.env.codec.encode(self.expert.act(self.env.sim)))


class ObservationExpert:
    """The task's expert as a policy of observations: what :meth:`demo.gym.env.DemoEnv.expert_policy` returns.

    Each observation must hold the simulator's state (an env made with ``sim_state=True``): the expert
    is put in that state on its own copy of the env (``env``: physics only, no cameras) and answers
    there, so observations from any number of envs, in any order, each get the expert's action for the
    state they were observed in, exactly what :class:`GymExpert` would answer in that env (the same
    per-episode choices, drawn from the episode's reset seed ``sim_seed``). It is still the privileged
    expert: it reads the simulator's state, not what a robot's sensors give.

    Interfaces: :meth:`act` (one observation -> one action), :meth:`predict` (stable-baselines3's, a batch:
    ``{key: [n, ...]}`` -> ``[n, A]``), and calling it as the ``imitation`` library calls a policy
    (``policy(obs, state, episode_start) -> (actions, state)``). Absolute action representations only
    (``joint_pos``, ``ee_abs``): a delta action is relative to the command an env executed last, which
    its observation does not hold.
    """

    def __init__(self, env: "DemoEnv"):
        if env.codec.fmt.rep.delta:
            env.close()
            raise DemoError("expert_policy", f"the {env.codec.fmt.name} action is relative to the last executed "
                                             "command, which observations do not hold: use an absolute action "
                                             "(joint_pos, ee_abs), or env.unwrapped.expert() on the env itself")
        self.env = env
        self._experts: dict[int, tuple[int, Expert]] = {}  # batch row -> (its episode's reset seed, expert)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The expert's action (float32, in the env's action space) in the state ``obs`` was observed in."""
        return self.predict({k: np.asarray(v)[None] for k, v in obs.items()})[0][0]

    def predict(self, observation: dict[str, np.ndarray], state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """Actions ``[n, A]`` for a batch of observations ``{key: [n, ...]}`` (stable-baselines3's signature;
        the expert is deterministic and keeps no recurrent state)."""
        states, seeds = self._state_of(observation)
        sim = self.env.sim
        actions = []
        for row, (s, seed) in enumerate(zip(states, seeds)):
            sim.set_state(s)
            known = self._experts.get(row)
            if known is None or known[0] != seed or (episode_start is not None and episode_start[row]):
                sim.seed = seed  # the expert draws its per-episode choices from it
                known = self._experts[row] = (seed, sim.expert())
            actions.append(self.env.normalized(self.env.codec.encode(known[1].act(sim))))
        return np.stack(actions).astype(np.float32), None

    def __call__(self, observation: dict[str, np.ndarray], state: Any = None,
                 episode_start: np.ndarray | None = None) -> tuple[np.ndarray, None]:
        return self.predict(observation, state, episode_start)

    def close(self) -> None:
        self.env.close()

    def _state_of(self, observation: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        """The batch's simulator states [n, S] and reset seeds, under either layout's keys."""
        keys = next((k for k in (("sim_state", "sim_seed"), ("sim.state", "sim.seed")) if k[0] in observation), None)
        if keys is None or keys[1] not in observation:
            raise DemoError("expert_policy", "the observation holds no simulator state (sim_state, sim_seed): make "
                                             "the env with sim_state=True")
        states = np.asarray(observation[keys[0]], dtype=np.float64)
        n = self.env.sim.features["sim.state"].shape[0]
        if states.ndim != 2 or states.shape[1] != n:
            raise DemoError("expert_policy", f"a simulator state of shape {states.shape} is not a batch of this "
                                             f"env's {n}-D states (another task, robot or option?)")
        return states, [int(s) for s in np.asarray(observation[keys[1]]).reshape(-1)]
