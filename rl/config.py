"""The configurations of the RL algorithms (PPO, GAIL/AIRL, linear IRL): every hyperparameter and its default.

Plain data (no torch), so that ``demo irl train --help`` shows the defaults and :mod:`demo.algorithms`
names them without loading a network. The algorithms themselves: :mod:`demo.rl.ppo`,
:mod:`demo.rl.adversarial`, :mod:`demo.rl.irl_linear`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import math
from typing import Any

from demo.errors import DemoError

ACTIONS = ("ee7", "joint_pos")  # what an RL policy outputs (demo.rl.ppo's module docstring)
KINDS = ("gail", "airl")
GAIL_REWARDS = ("softplus", "logit")
AIRL_REWARDS = ("logit", "f")
GAIL_INPUT_NAMES = ("sa", "ss", "s")  # (s, a), (s, s'), s': what GAIL's discriminator reads
METHODS = ("maxent", "apprenticeship")  # linear-reward IRL


@dataclass
class PPOConfig:
    """Everything a PPO run (and the RL inside GAIL, AIRL and linear IRL) is trained with."""

    task: str = "reach"
    task_options: dict[str, Any] = field(default_factory=dict)
    robot: str | None = None  # robot config TOML; default the built-in arm
    out: str = ""
    reward: str = "task"  # the dense task reward (demo.rl.rewards); IRL algorithms bring their own
    action: str = "joint_pos"  # joint_pos | ee7 (module docstring)
    obs_keys: tuple[str, ...] = ()  # default: demo.policies.observation's state keys
    seed: int = 0
    total_steps: int = 480_000  # environment (control) steps; reach: 92/100 in demo eval after 480,000 (28 min, shared CPU)
    num_envs: int = 16
    num_steps: int = 100  # control steps per environment per iteration (reach's horizon)
    epochs: int = 10
    minibatches: int = 8
    lr: float = 3e-4
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None  # stop an iteration's epochs once the approximate KL exceeds it
    norm_reward: bool = True  # scale rewards by a running std of the discounted return
    hidden: tuple[int, ...] = (256, 256)  # actor and critic MLP widths (tanh)
    init_log_std: float = -1.0  # initial log std of the Gaussian, normalised action units (std 0.37)
    max_ee_step: float = 0.02  # m per control step: the ee7 position bound
    max_rot_step: float = 0.1  # rad per control step: the ee7 rotation bound
    max_joint_step: float = 0.1  # rad per control step: the joint_pos bound (relative to the measured joints)
    eval_every: int = 10  # iterations between rollout evaluations (0: only at the end)
    eval_episodes: int = 20
    threads: int = 1

    def check(self) -> None:
        if self.action not in ACTIONS:
            raise DemoError("--action", f"RL acts in {' or '.join(ACTIONS)}, not {self.action!r}")
        positive = {"total_steps": self.total_steps, "num_envs": self.num_envs, "num_steps": self.num_steps,
                    "epochs": self.epochs, "minibatches": self.minibatches, "eval_episodes": self.eval_episodes}
        for name, value in positive.items():
            if value < 1:
                raise DemoError(f"--{name.replace('_', '-')}", f"must be at least 1, got {value}")
        if self.num_envs * self.num_steps < self.minibatches:
            raise DemoError("--minibatches", "more minibatches than transitions per iteration")
        if not (0 < self.gamma <= 1 and 0 <= self.gae_lambda <= 1 and self.clip > 0 and self.lr > 0):
            raise DemoError("--gamma", "needs 0 < gamma <= 1, 0 <= gae_lambda <= 1, clip > 0 and lr > 0")
        if min(self.max_ee_step, self.max_rot_step, self.max_joint_step) <= 0:
            raise DemoError("--max-ee-step", "action bounds must be > 0")

    @property
    def batch(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def iterations(self) -> int:
        return max(1, math.ceil(self.total_steps / self.batch))

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["obs_keys"], d["hidden"] = list(self.obs_keys), list(self.hidden)
        return d


@dataclass
class AdversarialConfig:
    rl: PPOConfig = field(default_factory=PPOConfig)
    data: str = ""  # the demonstrations (a store of the task, in the policy's action representation)
    kind: str = "gail"  # gail | airl
    demos: int | None = None  # the first N successful episodes (default all)
    inputs: str = "s"  # GAIL's discriminator input: sa (s, a), ss (s, s') or s (s'); AIRL is always (s, s') + log pi
    # the state the discriminator reads (ObsSpec keys); default the task's relative_goal_keys, else the policy's
    disc_obs_keys: tuple[str, ...] = ()
    disc_hidden: tuple[int, ...] = (256, 256)
    disc_lr: float = 3e-4
    disc_epochs: int = 2  # passes over each iteration's rollout
    disc_batch: int = 256  # policy (and as many expert) samples per discriminator step
    grad_penalty: float = 1.0
    init_bc: bool = True
    bc_steps: int = 2000
    gail_reward: str = "logit"  # gail: softplus (-log(1 - D), Ho & Ermon) | logit (log D - log(1 - D), DAC)
    airl_reward: str = "logit"  # airl: logit (f - log pi, the paper's) | f (without the entropy term)
    init: str = ""  # gail: start from this imitation run, the policy a residual over it (demo.rl.residual)
    scale: float = 0.1  # ... the residual's bound (ResidualConfig.scale)
    bc_coef: float = 1.0  # ... and the demonstrations kept in its BC term with this weight (ResidualConfig.bc_coef)

    def check(self) -> None:
        self.rl.check()
        if self.kind not in KINDS:
            raise DemoError("--algo", f"adversarial imitation is {' or '.join(KINDS)}, not {self.kind!r}")
        if self.gail_reward not in GAIL_REWARDS:
            raise DemoError("--gail-reward", f"GAIL's reward is {' or '.join(GAIL_REWARDS)}, not {self.gail_reward!r}")
        if self.airl_reward not in AIRL_REWARDS:
            raise DemoError("--airl-reward", f"AIRL's reward is {' or '.join(AIRL_REWARDS)}, not {self.airl_reward!r}")
        if self.inputs not in GAIL_INPUT_NAMES:
            raise DemoError("--inputs", f"GAIL's discriminator reads sa (s, a), ss (s, s') or s (s'), not {self.inputs!r}")
        if self.init and (self.kind != "gail" or self.inputs == "sa"):
            raise DemoError("--init", "starts GAIL with a state-only discriminator (--inputs s or ss) from an imitation "
                                      "run: a residual's actions are corrections, not the demonstrations' actions")
        if self.disc_epochs < 1 or self.disc_batch < 1 or self.grad_penalty < 0 or self.bc_steps < 0:
            raise DemoError("--disc-epochs", "disc_epochs and disc_batch must be >= 1, grad_penalty and bc_steps >= 0")

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["rl"], d["disc_hidden"], d["disc_obs_keys"] = self.rl.to_json(), list(self.disc_hidden), list(self.disc_obs_keys)
        return d


@dataclass
class FromImitationConfig:
    """What RL from an imitation run needs: the run, the PPO settings, the demonstrations kept in a BC term.
    The task, options, robot and action representation are the run's; :class:`ResidualConfig` and
    :class:`FinetuneConfig` add how the run is changed."""

    # PPO's settings but a narrower initial exploration (std 0.2 of the residual's bound: 54 -> 80% on pick's
    # monitor at 400,000 steps; PPO's 0.37: 68% at 302,000) and pick's horizon per rollout (docs/results.md)
    rl: PPOConfig = field(default_factory=lambda: PPOConfig(total_steps=400_000, num_steps=160, init_log_std=-1.6))
    init: str = ""  # the imitation run directory RL starts from
    data: str = ""  # demonstrations kept in a BC term during RL (a store of the run's task and actions)
    demos: int | None = None  # the first N successful ones (default all)
    bc_coef: float = 1.0  # the BC term's weight beside PPO's loss (with data)

    def check(self) -> None:
        self.rl.check()
        if not self.init:
            raise DemoError("--init", "name the imitation run RL starts from")
        if self.bc_coef < 0:
            raise DemoError("--bc-coef", f"must be >= 0, got {self.bc_coef}")

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["rl"] = self.rl.to_json()
        return d


@dataclass
class ResidualConfig(FromImitationConfig):
    """Residual RL on a frozen imitation run (:mod:`demo.rl.residual`)."""

    scale: float = 0.1  # the largest correction: this fraction of each action entry's half-range in the base's data

    def check(self) -> None:
        super().check()
        if not 0 < self.scale <= 1:
            raise DemoError("--scale", f"the residual's bound is a fraction in (0, 1] of each action's range, got {self.scale}")


@dataclass
class FinetuneConfig(FromImitationConfig):
    """Full fine-tuning: PPO on an imitation run's own weights (:mod:`demo.rl.finetune`)."""

    # exploration std 0.02 of each action's half-range (normalised units): the residual's at its defaults
    # (0.2 of a bound of 0.1), so both explore as far around the imitation policy; an iteration's epochs stop
    # once its KL passes 0.02 (the network's every weight moves the mean: PPO's clip alone let 3e-5 move it by 1.2)
    rl: PPOConfig = field(default_factory=lambda: PPOConfig(total_steps=400_000, num_steps=160, init_log_std=-3.9,
                                                            target_kl=0.02))
    # Adam's learning rate of the imitation weights (annealed with PPO's; the critic's is rl.lr). pick from 10 demos:
    # 3e-5 without the KL stop moved the policy by a KL of 1.2 in the first iteration and the monitor fell 56 -> 28%;
    # 3e-6 stayed at 54-58% for 154,000 steps; 1e-5 with the stop at 0.02 rose to 70-78% (docs/results.md)
    policy_lr: float = 1e-5

    def check(self) -> None:
        super().check()
        if self.policy_lr <= 0:
            raise DemoError("--policy-lr", f"must be > 0, got {self.policy_lr}")


@dataclass
class LinearIRLConfig:
    rl: PPOConfig = field(default_factory=PPOConfig)
    data: str = ""
    method: str = "maxent"  # maxent | apprenticeship
    demos: int | None = None
    inner_iterations: int = 5  # PPO iterations per reward update
    lr: float = 0.05  # maxent: Adam step on w
    l2: float = 0.0  # maxent: L2 penalty on w

    def check(self) -> None:
        self.rl.check()
        if self.method not in METHODS:
            raise DemoError("--algo", f"linear IRL is {' or '.join(METHODS)}, not {self.method!r}")
        if self.inner_iterations < 1 or self.lr <= 0 or self.l2 < 0:
            raise DemoError("--inner-iterations", "inner_iterations must be >= 1, lr > 0, l2 >= 0")

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["rl"] = self.rl.to_json()
        return d
