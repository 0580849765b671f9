"""The task's scripted expert behind a Gymnasium env, answering in the env's action representation."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

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
