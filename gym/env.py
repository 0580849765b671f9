"""One task of :mod:`demo.sim` as a ``gymnasium.Env``: what ``gymnasium.make("demo/Pick-v0", ...)`` builds.

Options (keyword arguments of ``gymnasium.make``):

- ``robot``: a robot config TOML (as ``demo collect --robot``); default the built-in arm.
- ``cameras``: camera images to observe, ``"NAME@WIDTHxHEIGHT"`` strings or ``(name, width, height)``
  (``front``, ``side``, ``top``, ``wrist``), e.g. ``["front@64x64", "wrist@64x64"]``, as
  ``demo collect --camera``; default none (state only).
- ``obs_keys``: the observations, by store feature name (``obs.joint_pos``, ``obs.image_front``, ...) or
  observation key (``joint_pos``, ``image_front``); default every ``obs.*`` feature of the env (the robot's
  and the task's state, then the cameras).
- ``action``: the action representation, ``joint_pos`` (default, what collection records), ``ee7``,
  ``ee_delta``, ``ee_abs`` or ``joint_vel``, with ``rotation`` / ``delta_frame`` as ``demo convert``
  takes them (:mod:`demo.convert.representations`); executed as ``demo eval`` executes a policy trained
  on it (:mod:`demo.gym.actions`).
- ``store_layout``: False (default): observations as RL and trajectory libraries take them, keys
  without the store's ``obs.`` prefix (``joint_pos``, ``image_front``: stable-baselines3 names a module
  per key, and a module name cannot hold a dot) and low-dim features flat (``object_pos`` (3 n,)). True:
  the store's feature names and per-frame shapes (``obs.object_pos`` (n, 3)), as :mod:`demo.rl` reads them.
- ``normalize_actions``: the action space is [-1, 1] per dimension, mapped linearly onto the
  representation's bounds (as RL libraries expect; refused where a bound is infinite, e.g. an
  unlimited joint in ``joint_pos``); the expert answers in it too. Default False: the representation's
  own units.
- ``sim_state``: the observation also holds the simulator's state, ``sim_state`` (float64, MuJoCo's
  ``mjSTATE_INTEGRATION``, a store's ``sim.state``) and ``sim_seed`` (int64 [1], the episode's reset seed,
  from which the expert draws its per-episode choices): what :meth:`DemoEnv.expert_policy` reads, so the
  expert can answer from observations alone (privileged: a policy that reads them reads the simulator).
  Default False.
- task options, e.g. ``blocks=2`` for stack; ``render_mode="rgb_array"`` with ``render_camera``
  (default ``front@256x256``, at most 640x480); ``hold_success_s`` (default 0.5 s, below).

Spaces (:mod:`demo.gym.spaces`): the observation ``Dict`` has the keys and dtypes of the features a
store collected from the same env records (named and shaped as ``store_layout`` says), bounded where
physical; the action
``Box`` is the representation's (or [-1, 1], ``normalize_actions``). ``env.spec.max_episode_steps`` is
the task's horizon (with its options), the step the env truncates itself at.

Seeds: ``reset(seed=s)`` calls the simulator's ``env.reset(s)``, so ``s`` is the *reset seed*, the
``seed`` column of a store. Episode ``i`` of ``demo collect --seed S`` starts from
``reset(seed=episode_seed(S, i))`` (:func:`demo.seeds.episode_seed`; on ``avoid``, whose episodes are
collected in pairs, ``episode_seed(S, i // 2)``). ``reset()`` without a seed draws a 32-bit reset seed
from the env's ``np_random``; ``info["seed"]`` says which.

Reward and episode end:

- ``reward`` = 1.0 at every step after which the task's success predicate holds, else 0.0 (sparse;
  the simulator's own reward).
- ``terminated`` once success has held for ``hold_success_s`` (0.5 s, 10 steps at 20 Hz), the rule
  the rollout loop of collection and ``demo eval`` ends episodes by
  (:class:`demo.sim.rollout.SuccessHold`), or as soon as the task has failed for good (avoid's
  ``collision``).
- ``truncated`` once the task's horizon (``env.unwrapped.horizon`` control steps) is reached.
- ``info``: ``success`` (the predicate after this step) and ``failure`` (the task's failure, e.g.
  ``"collision"``, else None).

Experts: ``env.unwrapped.expert()`` (:class:`demo.gym.expert.GymExpert`) answers for this env's current
state; ``env.unwrapped.expert_policy()`` (:class:`demo.gym.expert.ObservationExpert`) answers from
observations (``sim_state=True``), one per row of a batch, so it serves a vectorised env (SB3's
``predict``, the ``imitation`` library's policy callable).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from demo.convert.representations import make_format
from demo.errors import DemoError
from demo.gym.actions import ActionCodec
from demo.gym.expert import GymExpert, ObservationExpert
from demo.gym.spaces import action_space, observation_space
from demo.sim import make_env
from demo.sim.env import CONTROL_HZ
from demo.sim.render import parse_cameras
from demo.sim.robot_model import joint_limits
from demo.sim.rollout import HOLD_SUCCESS_S, SuccessHold

RENDER_MODES = ("rgb_array",)
STATE_KEYS = {False: ("sim_state", "sim_seed"), True: ("sim.state", "sim.seed")}  # by store_layout


class DemoEnv(gymnasium.Env):
    """A task environment (module docstring); ``sim`` is the :class:`demo.sim.env.Env` it drives."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": CONTROL_HZ}
    _spec: Any = None

    def __init__(
        self,
        task: str,
        robot: str | Path | None = None,
        cameras: Sequence[Any] | str = (),
        obs_keys: Sequence[str] | None = None,
        action: str = "joint_pos",
        rotation: str | None = None,
        delta_frame: str | None = None,
        render_mode: str | None = None,
        render_camera: str = "front@256x256",
        hold_success_s: float | None = HOLD_SUCCESS_S,
        normalize_actions: bool = False,
        store_layout: bool = False,
        sim_state: bool = False,
        **task_options: Any,
    ):
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise DemoError("render_mode", f"{render_mode!r} is not supported (choose from {', '.join(RENDER_MODES)})")
        self.render_mode = render_mode
        self._render_cameras = parse_cameras([render_camera])
        self._render_open = False
        self.sim = make_env(task, robot=robot, cameras=[cameras] if isinstance(cameras, str) else cameras,
                            **task_options)
        # What an expert policy's own copy of this env is made of (the physics and the actions, no cameras).
        self.physics_options: dict[str, Any] = dict(
            task=task, robot=robot, action=action, rotation=rotation, delta_frame=delta_frame,
            normalize_actions=normalize_actions, **task_options)
        try:
            self._setup(obs_keys, action, rotation, delta_frame, hold_success_s, normalize_actions, store_layout)
            if sim_state:
                self._add_state_keys()
        except Exception:
            self.sim.close()
            raise

    def _setup(self, obs_keys: Sequence[str] | None, action: str, rotation: str | None, delta_frame: str | None,
               hold_success_s: float | None, normalize_actions: bool, store_layout: bool) -> None:
        sim = self.sim
        observable = [k for k in sim.features if k.startswith("obs.")]
        keys = [k if k.startswith("obs.") else f"obs.{k}" for k in (observable if obs_keys is None else obs_keys)]
        unknown = [k for k in keys if k not in observable]
        if unknown or not keys:
            raise DemoError("obs_keys", f"unknown or no observation keys {unknown} (known: {', '.join(observable)})")
        self.obs_keys = tuple(keys)  # store feature names
        self.store_layout = store_layout
        # store feature name -> observation key (module docstring: store_layout)
        self.obs_names = {k: k if store_layout else k.removeprefix("obs.") for k in self.obs_keys}
        self.features = {k: sim.features[k] for k in self.obs_keys}
        by_feature = observation_space(sim.features, self.obs_keys, _joint_limits(sim), flat=not store_layout)
        self.observation_space = gymnasium.spaces.Dict({self.obs_names[k]: by_feature[k] for k in self.obs_keys})
        fmt = make_format(action, joint_names=sim.robot.arm_joints, rotation=rotation, delta_frame=delta_frame,
                          where="action")
        self.codec = ActionCodec(fmt, sim)
        self.action_spec = sim.action_spec if fmt.name == "joint_pos" else fmt.spec()
        units = action_space(fmt, _joint_limits(sim))
        self._action_low, self._action_span = None, None  # the affine map from [-1, 1], when normalised
        if normalize_actions:
            if not (np.isfinite(units.low).all() and np.isfinite(units.high).all()):
                raise DemoError("normalize_actions", f"the {fmt.name} action has an unbounded dimension (an "
                                                     "unlimited joint): it cannot be normalised to [-1, 1]")
            self._action_low, self._action_span = units.low.astype(np.float64), (units.high - units.low).astype(np.float64)
            units = gymnasium.spaces.Box(-1.0, 1.0, units.shape, np.float32)
        self.action_space = units
        self.horizon = sim.horizon
        self._hold = SuccessHold(hold_success_s, sim.fps)
        self.reset_seed: int | None = None
        self.state_keys: tuple[str, ...] = ()

    def _add_state_keys(self) -> None:
        """The simulator's state and the reset seed in the observation (module docstring: ``sim_state``)."""
        n = self.sim.features["sim.state"].shape[0]
        self.state_keys = STATE_KEYS[self.store_layout]
        state, seed = self.state_keys
        self.observation_space = gymnasium.spaces.Dict({
            **self.observation_space.spaces,
            state: gymnasium.spaces.Box(-np.inf, np.inf, (n,), np.float64),
            seed: gymnasium.spaces.Box(0, 2**32 - 1, (1,), np.int64),
        })

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode from reset seed ``seed`` (module docstring); ``options`` takes nothing."""
        super().reset(seed=seed)
        if options:
            raise DemoError("reset", f"unknown reset option(s) {', '.join(map(str, options))} (none are taken)")
        self.reset_seed = int(seed) if seed is not None else int(self.np_random.integers(2**32))
        obs = self.sim.reset(self.reset_seed)
        self.codec.reset(self.sim)
        self._hold.reset()
        return self._observation(obs), {"seed": self.reset_seed}

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._action_low is not None:  # [-1, 1] -> the representation's units
            action = self._action_low + (np.asarray(action, dtype=np.float64) + 1.0) * 0.5 * self._action_span
        obs, reward, success, truncated, _ = self.sim.step(self.codec.command(action))
        failure = self.sim.task.failure(self.sim)
        terminated = self._hold.update(bool(success)) or failure is not None
        info = {"success": bool(success), "failure": failure}
        return self._observation(obs), float(reward), bool(terminated), bool(truncated), info

    def render(self) -> np.ndarray | None:
        """The ``render_camera`` image (uint8 [height, width, 3]) of the current state."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() without a render_mode: make the env with render_mode='rgb_array'")
            return None
        if not self._render_open:
            self._render_cameras.open(self.sim.model)
            self._render_open = True
        out: dict[str, np.ndarray] = {}
        self._render_cameras.render(self.sim.data, out)
        return next(iter(out.values()))

    def close(self) -> None:
        """Close the renderers (observation cameras and ``render``); calling it again does nothing."""
        self._render_cameras.close()
        self._render_open = False
        self.sim.close()

    # ------------------------------------------------------------------ demo API
    def expert(self, rng: np.random.Generator | None = None, **style: Any) -> GymExpert:
        """The task's scripted expert for the current episode (call after ``reset``); ``rng`` and
        ``style`` as :meth:`demo.sim.env.Env.expert` takes them (default: per-episode choices drawn
        from the reset seed)."""
        return GymExpert(self, self.sim.expert(rng, **style))

    def expert_policy(self) -> ObservationExpert:
        """The task's expert as a policy of observations alone (this env made with ``sim_state=True``),
        answering in this env's action space, for batches of observations from any number of copies of
        this env (:class:`demo.gym.expert.ObservationExpert`)."""
        if not self.state_keys:
            raise DemoError("expert_policy", "the observations hold no simulator state: make the env with "
                                             "sim_state=True (or use expert(), which reads this env)")
        return ObservationExpert(DemoEnv(**self.physics_options))

    def normalized(self, action: np.ndarray) -> np.ndarray:
        """An action in the representation's units as the action space takes it ([-1, 1] when normalised)."""
        if self._action_low is None:
            return action
        return (2.0 * (np.asarray(action, dtype=np.float64) - self._action_low) / self._action_span - 1.0).astype(np.float32)

    @property
    def spec(self) -> Any:
        """The registered spec, its ``max_episode_steps`` the task's horizon: the env truncates itself there."""
        return self._spec

    @spec.setter
    def spec(self, value: Any) -> None:  # gymnasium.make sets it after construction
        self._spec = value if value is None or value.max_episode_steps else dataclasses.replace(
            value, max_episode_steps=int(self.horizon))

    def _observation(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        # Copies (the simulator reuses its last observation while the state is unchanged, and a caller keeps
        # what it is given), named and shaped as store_layout says (module docstring).
        flat, names = not self.store_layout, self.obs_names
        out = {names[k]: np.array(obs[k]).reshape(-1) if flat and obs[k].dtype != np.uint8 else np.array(obs[k])
               for k in self.obs_keys}
        if self.state_keys:
            state, seed = self.state_keys
            out[state] = self.sim.get_state()
            out[seed] = np.array([self.reset_seed], dtype=np.int64)
        return out


def _joint_limits(sim: Any) -> np.ndarray:
    """[n_arm, 2] (rad): the arm joints' ranges, infinite where a joint is unlimited."""
    return joint_limits(sim.model, [sim.model.joint(j).id for j in sim.robot.arm_joints])
