"""Residual RL on a frozen imitation policy (ResiP: Ankile et al. 2024), top to bottom.

``demo irl train --algo residual --init RUN --out RUN2`` keeps the imitation run ``RUN`` (BC with chunks,
diffusion, ACT, a DAgger run: anything ``demo eval`` runs from state) exactly as it was trained and learns,
by PPO (:mod:`demo.rl.ppo`), a bounded correction added to its every action
(:mod:`demo.policies.residual`): the base policy keeps doing what the demonstrations taught, and RL only
refines it where the demonstrations ran out. A correction at most ``scale`` of each action entry's
half-range in the base's data cannot take the arm anywhere the base did not already go, which is what
keeps the fine-tuned policy near its starting success while it learns.

**Per control step** (:class:`ResidualController`): each environment has the base policy's own
:class:`~demo.policies.actor.PolicyActor` (observation history, chunks, temporal ensembling); the base
action ``b`` for the frame is merged from its chunks; the residual (PPO's Gaussian) reads ``[state, b]``,
standardised by running statistics; the executed command is ``b + bound * clip(a, -1, 1)``, its binary
gripper rounded as the base's execution rounds it. Nothing of the base is trained.

**Demonstrations in RL** (``STORE``, DAPG's and RLPD's point: keep what the demonstrations say while RL
explores): every PPO minibatch step adds ``bc_coef`` times the squared error between the residual's mean
and the correction that would turn the base's action at a demonstrated state into the demonstrator's
(the base policy replayed over each demonstration's frames, chunks merged as in a rollout; the target
clipped to the bound), on as many demonstrated states as the minibatch has transitions.

**A pixel policy as the base**: the environments render the cameras it reads, and the residual still
reads the simulator's state (the arm's and the objects'): privileged information a real robot would have to
estimate, as the state-feedback experts have it here.

**Reward**: the task's dense reward (:mod:`demo.rl.rewards`: pick's reach, lift and success terms), or
with ``--reward RUN`` a reward an IRL run learned, as PPO takes them. The task, its options and the robot
are the base run's. Training episodes come from the RL seed stream, disjoint from the demonstrations
and from ``demo eval``.

**Curves**: the monitor evaluates the corrected policy before the first update (the base policy's own
success: the starting line, ``metrics["start"]``) and every ``eval_every`` iterations after it; the
figure draws success and return against environment steps with the starting line, and the summary holds
the lowest monitored success (how far fine-tuning ever fell below its start).

The run directory evaluates with ``demo eval``: its ``run.json`` holds the base's policy record and a
``residual`` section, ``policy.safetensors`` the base's weights unchanged and the residual's beside them.
"""

from __future__ import annotations

from collections.abc import Callable
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import torch

from demo.errors import DemoError
from demo.evaluation.evaluate import pick_robot
from demo.policies import checkpoint as ckpt
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import ObsSpec
from demo.policies.residual import Residual, residual_bound, residual_input
from demo.progress import Progress
from demo.rl.config import ACTIONS, FromImitationConfig, PPOConfig, ResidualConfig
from demo.rl.expert_data import demonstrations
from demo.rl.ppo import Controller, EnvPool, RLRun, learned_reward
from demo.store import EpisodeStore


class ResidualController(Controller):
    """The agent's actions as corrections of a frozen policy's (module docstring)."""

    def __init__(self, pool: EnvPool, base: ckpt.PolicyBundle, bound: np.ndarray):
        super().__init__(pool, base.action_norm)
        self.base, self.bound = base, bound
        self.actors = [base.actor() for _ in pool.envs]
        self.base_actions = np.zeros((len(pool.envs), base.action.dim), np.float32)

    @property
    def obs_dim(self) -> int:
        return self.pool.obs_spec.dim + self.base.action.dim

    def reset(self, i: int) -> None:
        self.actors[i].reset(self.pool.seeds[i], self.pool.envs[i])

    def observe(self, i: int, frame: dict[str, np.ndarray]) -> np.ndarray:
        self.base_actions[i] = self.actors[i].base_action(frame)
        return residual_input(self.pool.obs_spec, frame, self.base_actions[i])

    def command(self, actions: np.ndarray, frames: dict[str, np.ndarray]) -> np.ndarray:
        return np.stack([actor.finish(base + self.bound * a)
                         for actor, base, a in zip(self.actors, self.base_actions, actions)])


class ResidualRun(RLRun):
    """PPO on a residual over the frozen imitation policy ``config.init`` (module docstring)."""

    def __init__(self, config: FromImitationConfig, *, name: str = "residual", progress: Progress | None = None,
                 overwrite: bool = False, command: str | None = None):
        """``name``: the algorithm recorded (``residual``; ``gail`` when GAIL's reward trains it)."""
        config.check()
        self.from_imitation = config
        self.base = ckpt.load_bundle(config.init)
        self.check_base(config)
        rl = _rl_config(config, self.base)
        robot = pick_robot(self.base, None)
        super().__init__(rl, name=name, progress=progress, overwrite=overwrite, command=command, robot=robot,
                         cameras=self.base.obs_spec.cameras())
        self.record.update({
            **self.change_record(),
            "init": {"run": str(Path(config.init).resolve()), "algo": self.base.algo},
            "data": self.base.run.get("data"),
            "train": config.to_json(),
        })
        self.metrics["start"] = None
        self.bc_coef = config.bc_coef
        self.demo_inputs: np.ndarray | None = None  # [M, D] the agent's raw inputs at demonstrated states
        self.demo_targets: np.ndarray | None = None  # [M, A] the agent's normalised actions there
        if config.data:
            self.demo_inputs, self.demo_targets, episodes = self.demonstration_targets(config.data, config.demos)
            self.record["demonstrations"] = {"path": str(Path(config.data).resolve()), "episodes": episodes,
                                             "states": int(len(self.demo_inputs)), "bc_coef": config.bc_coef}
            self.bc_rng = np.random.default_rng([config.rl.seed, 0xBC])

    def policy_record(self) -> dict[str, Any]:
        return self.base.run["policy"]  # the base policy: demo eval rebuilds it from here

    def check_base(self, config: FromImitationConfig) -> None:
        """Refuse a base run this algorithm cannot start from (any runs under a residual)."""
        assert isinstance(config, ResidualConfig)
        self.scale = config.scale

    def change_record(self) -> dict[str, Any]:
        """What ``run.json`` records of the change to the base policy (the residual's record)."""
        return {"residual": self.residual().to_json()}

    def demonstration_targets(self, path: str, demos: int | None) -> tuple[np.ndarray, np.ndarray, int]:
        """The agent's raw inputs ``[M, D]`` at demonstrated states and its normalised actions there ``[M, A]`` (the
        BC term's), and the number of demonstrations."""
        return demonstration_targets(path, demos, self.base, self.pool.obs_spec, self.controller.bound)

    def make_controller(self) -> ResidualController:
        return ResidualController(self.pool, self.base, residual_bound(self.base.action_norm, self.scale))

    def residual(self) -> Residual:
        """The correction as it is now (the agent's policy and observation statistics)."""
        return Residual(self.agent.policy, self.pool.obs_spec, self.agent.obs_norm, self.controller.bound, self.scale)

    def bundle(self) -> ckpt.PolicyBundle:
        return dataclasses.replace(self.base, residual=self.residual(), run=self.record, path=self.out)

    def policy_weights(self) -> tuple[dict[str, torch.Tensor], MinMaxNormalizer, MinMaxNormalizer]:
        return self.base.policy.state_dict(), self.base.obs_norm, self.base.action_norm

    def extra_tensors(self) -> dict[str, torch.Tensor]:
        return self.residual().tensors()

    def auxiliary_loss(self) -> Callable[[], torch.Tensor] | None:
        """The BC term on the demonstrations (module docstring), with this iteration's input statistics."""
        if self.demo_inputs is None or self.bc_coef == 0:
            return None
        agent, c = self.agent, self.config
        inputs = torch.from_numpy(np.clip(agent.obs_norm.normalize(self.demo_inputs), -OBS_CLIP, OBS_CLIP))
        targets = torch.from_numpy(self.demo_targets)
        size = c.batch // c.minibatches

        def bc_term() -> torch.Tensor:
            idx = torch.from_numpy(self.bc_rng.integers(len(inputs), size=size))
            return self.bc_coef * ((agent.policy.mean(inputs[idx]) - targets[idx]) ** 2).mean()

        return bc_term

    def evaluate(self) -> dict[str, Any] | None:
        entry = super().evaluate()
        if entry is not None and self.metrics["start"] is None:
            self.metrics["start"] = entry
        return entry

    def final_metrics(self) -> dict[str, Any]:
        evals = [e["success_rate"] for e in self.metrics["eval"]]
        start = self.metrics["start"] or {}
        return {**super().final_metrics(), "start_success_rate": start.get("success_rate"),
                "min_success_rate": min(evals) if evals else None}

    def run(self, config: FromImitationConfig) -> dict[str, Any]:
        """Train: the starting line (the base policy, before any update), every iteration; the summary."""
        reward = None
        if config.rl.reward != "task":
            reward, self.record["learned_reward"] = learned_reward(config.rl.reward, self)
        self.open()
        self.evaluate()  # the starting line: the base policy as it was trained
        self.learn(reward)
        return self.finish()


def frame_keys(base: ckpt.PolicyBundle, obs_spec: ObsSpec) -> list[str]:
    """The frame entries a base policy and an agent reading ``obs_spec`` read."""
    return list(dict.fromkeys([*base.obs_spec.source_keys, *base.obs_spec.images, *obs_spec.source_keys,
                               *([base.relative.obs_key] if base.relative is not None else [])]))


def demonstration_targets(path: str, demos: int | None, base: ckpt.PolicyBundle, obs_spec: ObsSpec,
                          bound: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """The residual's raw inputs ``[M, D]`` at every state of the first ``demos`` successful demonstrations,
    the corrections ``[M, A]`` (normalised by ``bound``, clipped to [-1, 1]) from the base policy's action
    there (replayed over each episode's frames in order) to the demonstrated one, and the episode count."""
    task, keys = str(base.task.get("name")), frame_keys(base, obs_spec)
    inputs, targets = [], []
    actor = base.actor()
    with EpisodeStore.open(path) as store:
        chosen = demonstrations(store, path, task, base.obs_spec, base.action, demos)
        for j, index in enumerate(chosen):
            data = store.read_episode(int(index), [*keys, "action"])
            actor.reset(j)
            for t, action in enumerate(np.asarray(data["action"], np.float32)):
                frame = {k: data[k][t] for k in keys}
                b = actor.base_action(frame)
                inputs.append(residual_input(obs_spec, frame, b))
                targets.append(np.clip((action - b) / np.maximum(bound, 1e-9), -1.0, 1.0))
    return np.asarray(inputs, np.float32), np.asarray(targets, np.float32), len(chosen)


def _rl_config(config: FromImitationConfig, base: ckpt.PolicyBundle) -> PPOConfig:
    """PPO's configuration for a residual over ``base``: its task, options and action representation."""
    action = base.action.name
    if action not in ACTIONS:
        raise DemoError(config.init, f"acts in {action!r}; a residual corrects {' or '.join(ACTIONS)} actions "
                                     "(demo convert the data and train the base in one of them)")
    if base.tokenizer is not None:
        raise DemoError(config.init, "follows instructions; a residual over an instruction-conditioned policy is not built")
    task = base.task.get("name")
    if not task:
        raise DemoError(config.init, "records no task")
    return dataclasses.replace(config.rl, task=task, task_options=dict(base.task.get("options") or {}), action=action)


def train(config: ResidualConfig, *, progress: Progress | None = None, overwrite: bool = False,
          command: str | None = None) -> dict[str, Any]:
    """Residual RL into ``config.rl.out`` over the imitation run ``config.init``; returns the summary."""
    with ResidualRun(config, progress=progress, overwrite=overwrite, command=command) as rl:
        return rl.run(config)
