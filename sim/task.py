"""What a task is (scene additions, randomised reset, observations, success) and what an expert is.

A task keeps every per-episode random quantity *in the simulator state*: objects are free bodies
(``qpos``), goals and obstacles are mocap bodies (``mocap_pos``/``mocap_quat``), so
``env.set_state(env.get_state())`` restores an episode exactly and an expert can be asked what to
do in any state.

Experts are state-feedback policies: :meth:`Expert.act` reads the current simulator state (EE pose,
object poses, contacts) and returns an action; it never counts steps or reads the clock. Their
per-episode random choices (e.g. avoid's side, a style variation) are drawn at construction.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, ClassVar

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import axis_angle_quat, quat_step
from demo.store import FeatureSpec

if TYPE_CHECKING:
    from demo.sim.env import Env
    from demo.sim.scene import BaseFrame


class Task:
    """Base class. Subclasses set ``name``, ``defaults`` (task options) and ``expert_class``."""

    name: ClassVar[str] = ""
    defaults: ClassVar[dict[str, Any]] = {}
    expert_class: ClassVar[type["Expert"]]
    # Scene geoms the expert's IK keeps the arm away from (mink collision avoidance).
    avoid_geoms: ClassVar[tuple[str, ...]] = ()
    # Uniform noise (rad) added to the home arm configuration at reset.
    arm_noise: ClassVar[float] = 0.03
    # The goal relative to what the arm controls, as observation keys (demo.policies.observation.ObsSpec,
    # differences allowed): what an adversarial imitation discriminator reads by default
    # (demo.rl.adversarial). No per-episode constant it could memorise to tell the demonstrations'
    # few goals from the policy's new ones, nothing of the arm's redundant posture. Empty: the policy's.
    relative_goal_keys: ClassVar[tuple[str, ...]] = ()
    # Options that change only how an episode's instruction is worded, not the scene: a policy trained with
    # one value may be evaluated with another (held-out paraphrases).
    wording_options: ClassVar[tuple[str, ...]] = ()
    # What the current episode asks for in words ("" for a task whose goal the scene shows; demo.sim.pick's
    # coloured cubes name their target here at each reset)
    instruction: str = ""

    @property
    def goals(self) -> int:
        """How many goals the words can name in one scene (0: a task whose goal the scene shows)."""
        return 0

    def shift_goal(self, offset: int) -> None:
        """Ask, in the scene :meth:`reset` drew, for the goal ``offset`` places after the one it drew (modulo
        :attr:`goals`), the instruction re-worded with the same template: one scene, another goal, told only
        in words (``demo collect --every-goal``)."""
        raise DemoError(self.name, "names no goal in words")

    def __init__(self, **options: Any):
        unknown = sorted(set(options) - set(self.defaults))
        if unknown:
            known = ", ".join(self.defaults) or "none"
            raise DemoError(self.name, f"unknown task option(s) {', '.join(unknown)} (known: {known})")
        self.options = {**self.defaults, **options}

    @property
    def horizon(self) -> int:
        """Maximum number of control steps of an episode."""
        raise NotImplementedError

    def build(self, spec: mujoco.MjSpec, base: "BaseFrame") -> None:
        """Add the task's bodies (objects, goal markers, obstacles) to the scene."""

    def bind(self, env: "Env") -> None:
        """Resolve ids in the compiled model."""

    def reset(self, env: "Env", rng: np.random.Generator) -> None:
        """Randomise objects and goals (the arm is already at its noisy home configuration)."""

    def features(self, env: "Env") -> dict[str, FeatureSpec]:
        """Task observations (``obs.*``) beyond the robot's own."""
        return {}

    def observe(self, env: "Env", out: dict[str, np.ndarray]) -> None:
        """Fill the task's observations into ``out``."""

    def after_step(self, env: "Env") -> None:
        """Called after every control step: latch events into the simulator state (avoid's touch)."""

    def success(self, env: "Env") -> bool:
        raise NotImplementedError

    def failure(self, env: "Env") -> str | None:
        """Why the episode has failed for good (e.g. avoid's ``"collision"``), None while it has not."""
        return None


@dataclasses.dataclass
class ExpertParams:
    """Strategy parameters shared by every expert; tasks extend this dataclass."""

    speed: float = 1.0  # scale of the EE speed
    max_speed: float = 0.35  # m/s at speed 1
    max_rot_speed: float = 2.0  # rad/s at speed 1


class Expert:
    """A scripted state-feedback expert. ``style`` keys are fields of the task's params dataclass.

    ``vary=True`` draws the task's strategy variations
    (``VARIATIONS``) from ``rng`` once, at construction: one episode is consistent, episodes differ
    (an inconsistent operator). Explicit style keys win over drawn ones.
    """

    Params: ClassVar[type[ExpertParams]] = ExpertParams
    VARIATIONS: ClassVar[dict[str, tuple[float, float]]] = {}  # field -> uniform (low, high)

    def __init__(
        self,
        env: "Env",
        rng: np.random.Generator | None = None,
        vary: bool = False,
        **style: Any,
    ):
        if rng is None:
            # Per-episode choices stay deterministic for a seed and still differ across seeds.
            rng = np.random.default_rng([0 if env.seed is None else env.seed, 7919])
        self.rng = rng
        names = {f.name for f in dataclasses.fields(self.Params)}
        unknown = sorted(set(style) - names)
        if unknown:
            raise DemoError(
                f"{env.task_name} expert", f"unknown style option(s) {', '.join(unknown)} (known: vary, {', '.join(sorted(names))})"
            )
        drawn: dict[str, Any] = {}
        if vary:
            for key, (lo, hi) in self.VARIATIONS.items():
                drawn[key] = float(rng.uniform(lo, hi))
        self.p = self.Params(**{**drawn, **style})
        if not self.p.speed > 0:
            raise DemoError(f"{env.task_name} expert", f"speed must be > 0, got {self.p.speed}")
        self.ee_target = np.concatenate([*env.ee_pose()])
        # Added to every position the expert aims at (m, base frame). Zero for a perfect expert; an
        # operator model may set it each step to make the hand wander (a bounded offset that the
        # feedback follows), which a bias on the joint targets cannot do (see `move`).
        self.aim_offset = np.zeros(3)
        self._action = np.zeros(env.action_spec.dim)
        self._setup(env)

    def _setup(self, env: "Env") -> None:
        """Per-episode choices drawn from ``self.rng`` (called once at construction)."""

    @property
    def mode(self) -> str | None:
        """The demonstration mode this expert is following (e.g. "left"/"right"), or None."""
        return None

    def act(self, env: "Env") -> np.ndarray:
        raise NotImplementedError

    # ------------------------------------------------------------------ motion primitive
    def move(
        self, env: "Env", pos: np.ndarray, quat: np.ndarray, grip: float, speed: float = 1.0,
        ee: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """One control step toward the EE pose (base frame) at the expert's speed; gripper 0..1.
        ``ee``: ``env.ee_pose()`` of the current state, when the caller has it already.

        The commanded waypoint is at most ``speed * max_speed * dt`` away from the current EE
        position (and ``max_rot_speed * dt`` in angle); IK turns it into joint targets. The targets
        are relative to the measured state, so a disturbance of the *executed* joint targets that
        moves the EE by more than one such step per control step (e.g. a persistent bias of a few
        centi-radians) outruns the correction; perturb ``aim_offset`` instead.
        """
        pos = pos + self.aim_offset
        ee_pos, ee_quat = env.ee_pose() if ee is None else ee
        scale = self.p.speed * speed
        dt = 1.0 / env.fps
        step = scale * self.p.max_speed * dt
        d = pos - ee_pos
        n = math.sqrt(float(d.dot(d)))  # d @ d
        wp = pos if n <= step else ee_pos + d * (step / n)
        wq = quat_step(ee_quat, quat, scale * self.p.max_rot_speed * dt)
        self.ee_target[:3] = wp
        self.ee_target[3:] = wq
        q = env.ik_step(wp, wq)
        a = self._action
        a[: q.shape[0]] = q
        a[-1] = grip
        return a.copy()


def place_free_body(env: "Env", joint_id: int, pos: np.ndarray, yaw: float) -> None:
    """Put a free body at rest at ``pos`` (base frame, m) with heading ``yaw`` about base z."""
    m, d = env.model, env.data
    a, v = m.jnt_qposadr[joint_id], m.jnt_dofadr[joint_id]
    d.qpos[a : a + 3] = env.to_world(np.asarray(pos, dtype=np.float64))
    d.qpos[a + 3 : a + 7] = env.quat_to_world(axis_angle_quat(np.array([0.0, 0.0, 1.0]), yaw))
    d.qvel[v : v + 6] = 0.0
