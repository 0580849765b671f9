"""Meta-World as a named environment adapter: ``--env metaworld:<task>`` (:mod:`demo.sim.foreign`), its
scripted policies as experts (``--expert metaworld``), its task sets (``MT10``, ``MT50``).

An optional dependency, installed by name (``pip install metaworld==3.1.1 --no-deps``: it pins
``mujoco==3.3.0``, and runs on the project's MuJoCo 4 with the one change below); nothing else
needs it, and a command that does without it says so in one line.

- **The environment** is the benchmark's own: ``gymnasium.make("Meta-World/MT1", env_name=<task>,
  seed=<benchmark seed>)``, whose resets draw among the task's 50 goal and object variations (the
  MT protocol), 39-D state, a 4-D action (end-effector displacement and gripper), 500 steps, and its
  own ``info["success"]``.
- **MuJoCo 4**: a weld constraint's ``eq_data`` grew from 11 to 12 numbers: the 12th, new, tells
  ``mj_setConst`` to recompute the relative pose from ``qpos0`` when nonzero (MuJoCo 4's changelog), and
  Meta-World's welds compile with it at 1. Meta-World's ``reset_mocap_welds`` writes 11 values and fails
  to broadcast; :func:`_mujoco4_welds` writes the same 11 and a 0 (keep the pose it sets; nothing in
  this path calls ``mj_setConst``, so 0 and 1 measure the same). Measured against Meta-World on its
  own MuJoCo 3.3.0, 50 episodes of each MT10 task's scripted policy: the same success count on all
  ten tasks, mean lengths within 0.3 steps on eight (docs/environments.md).
- **The expert** of an episode is ``metaworld.policies.ENV_POLICY_MAP[task]()``'s ``get_action(obs)``,
  a function of the 39-D state alone.
- **From a camera** (``--env-opt camera=corner@64x64``, :class:`CameraObservation`): the observation
  becomes ``{"image_corner": HxWx3 uint8, "state": 4-D}``, the image of a Meta-World camera (``corner``,
  ``corner2``, ``topview``, ...; turned 180 degrees, Meta-World's corner camera renders upside down) and
  the end-effector position (m, world frame) with the gripper's opening: the policy sees no object
  or goal position. The expert still reads the full 39-D state (privileged: the wrapper keeps it).
  Shadows and reflections are off: on this machine's software EGL they cost 7-10x the frame rate
  (5.9 frames/s with them at 64x64, 43 without shadows, 56 without either), and at 64x64 the image
  barely changes.
  ``--env-opt env_state=true`` records the 39-D state beside them as ``obs.env_state``: never a default input
  of a policy (:data:`demo.policies.observation.PRIVILEGED_KEYS`), a target for ``demo train --aux-target``.
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium
import numpy as np

from demo.errors import DemoError

ADAPTER = "metaworld"
INSTALL = "pip install --no-deps metaworld==3.1.1"
BENCHMARK_SEED = 0  # the seed Meta-World's MT1 benchmark draws its 50 task variations with


def _import() -> Any:
    try:
        import metaworld  # deferred: an optional dependency, imported where it is used
    except ImportError:
        raise DemoError("--env metaworld", f"Meta-World is not installed ({INSTALL})") from None
    return metaworld


def _mujoco4_welds() -> None:
    """Meta-World's mocap-weld reset, writing its 11 weld parameters into MuJoCo 4's 12 (module docstring)."""
    import mujoco  # deferred: only with Meta-World

    from metaworld import sawyer_xyz_env  # deferred: an optional dependency

    base = sawyer_xyz_env.SawyerMocapBase
    if getattr(base.reset_mocap_welds, "demo_mujoco4", False):
        return

    def reset_mocap_welds(self: Any) -> None:
        if self.model.nmocap > 0 and self.model.eq_data is not None:
            for i in range(self.model.eq_data.shape[0]):
                if self.model.eq_type[i] == mujoco.mjtEq.mjEQ_WELD:
                    self.model.eq_data[i] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 5.0, 0.0]

    reset_mocap_welds.demo_mujoco4 = True  # type: ignore[attr-defined]
    base.reset_mocap_welds = reset_mocap_welds


def task_set(name: str) -> list[str]:
    """The tasks of a Meta-World set (``MT10``, ``MT50``), or ``[name]`` for one task."""
    _import()
    from metaworld import env_dict  # deferred: an optional dependency

    sets = {"MT10": list(env_dict.MT10_V3), "MT50": list(env_dict.MT50_V3)}
    if name in sets:
        return sets[name]
    if name not in env_dict.ALL_V3_ENVIRONMENTS:
        raise DemoError(f"--env metaworld:{name}", f"is no Meta-World task nor set (sets: {', '.join(sets)}; "
                                                   "tasks e.g. pick-place-v3)")
    return [name]


# Each task as an instruction (demo.policies.instruction): what its success asks for, in words (Meta-World's
# task descriptions, shortened). A task without an entry reads as its name.
INSTRUCTIONS: dict[str, str] = {
    "assembly": "put the ring on the peg", "basketball": "dunk the ball into the basket",
    "bin-picking": "move the cube from one bin to the other", "box-close": "put the lid on the box",
    "button-press-topdown": "press the button from the top", "button-press-topdown-wall": "press the button behind the wall from the top",
    "button-press": "press the button", "button-press-wall": "press the button behind the wall",
    "coffee-button": "press the button of the coffee machine", "coffee-pull": "pull the mug from the coffee machine",
    "coffee-push": "push the mug under the coffee machine", "dial-turn": "turn the dial",
    "disassemble": "pick the ring off the peg", "door-close": "close the door", "door-lock": "lock the door",
    "door-open": "open the door", "door-unlock": "unlock the door", "hand-insert": "put the hand into the hole",
    "drawer-close": "close the drawer", "drawer-open": "open the drawer", "faucet-open": "turn the faucet on",
    "faucet-close": "turn the faucet off", "hammer": "hammer the nail into the wall",
    "handle-press-side": "press the handle down from the side", "handle-press": "press the handle down",
    "handle-pull-side": "pull the handle up from the side", "handle-pull": "pull the handle up",
    "lever-pull": "pull the lever up", "pick-place-wall": "pick the puck and place it at the goal behind the wall",
    "pick-out-of-hole": "pick the peg out of the hole", "pick-place": "pick the puck and place it at the goal",
    "plate-slide": "slide the plate into the cabinet", "plate-slide-side": "slide the plate into the cabinet from the side",
    "plate-slide-back": "slide the plate out of the cabinet",
    "plate-slide-back-side": "slide the plate out of the cabinet to the side",
    "peg-insert-side": "insert the peg into the hole from the side", "peg-unplug-side": "unplug the peg to the side",
    "soccer": "kick the ball into the goal", "stick-push": "push the bottle with the stick",
    "stick-pull": "pull the bottle with the stick", "push": "push the puck to the goal",
    "push-wall": "push the puck to the goal behind the wall", "push-back": "push the puck back to the goal",
    "reach": "reach the goal", "reach-wall": "reach the goal behind the wall", "shelf-place": "put the block on the shelf",
    "sweep-into": "sweep the puck into the hole", "sweep": "sweep the puck off the table",
    "window-open": "slide the window open", "window-close": "slide the window closed",
}


def instruction(task: str) -> str:
    """The task (``pick-place-v3``) as an instruction (``pick the puck and place it at the goal``)."""
    name = task.rsplit("-v", 1)[0] if task.rsplit("-v", 1)[-1].isdigit() else task
    return INSTRUCTIONS.get(name, name.replace("-", " "))


def make(task: str, seed: int = BENCHMARK_SEED, camera: str | None = None, env_state: bool = False,
         **options: Any) -> gymnasium.Env:
    """The Meta-World task ``task`` (e.g. ``pick-place-v3``) as the benchmark builds it (module docstring);
    ``camera`` (``NAME@WxH``): observed from that camera and the 4-D end-effector state instead, with the 39-D
    state as ``env_state`` too where ``env_state`` is set."""
    if len(task_set(task)) > 1:
        raise DemoError(f"--env metaworld:{task}", "names a set of tasks, not one environment (demo.sim.foreign_set)")
    if env_state and camera is None:
        raise DemoError("--env-opt env_state", "records the state beside a camera's image; without --env-opt camera "
                                               "the observation is the state already")
    _mujoco4_welds()
    # disable_env_checker: its passive checker warns about Meta-World's own spaces on every make
    env = gymnasium.make("Meta-World/MT1", env_name=task, seed=seed, disable_env_checker=True, **options)
    return env if camera is None else CameraObservation(env, camera, bool(env_state))


PROPRIO = slice(0, 4)  # the 39-D state's end-effector position (m) and gripper opening


class CameraObservation(gymnasium.ObservationWrapper):
    """A Meta-World env observed from one of its cameras plus the 4-D end-effector state (module docstring)."""

    def __init__(self, env: gymnasium.Env, camera: str, env_state: bool = False):
        super().__init__(env)
        import mujoco  # deferred: only with Meta-World

        from demo.sim.render import parse_camera  # NAME@WxH, as --camera takes it

        self.camera, width, height = parse_camera(camera, "--env-opt camera")
        model = env.unwrapped.model
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, self.camera) < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise DemoError("--env-opt camera", f"Meta-World has no camera {self.camera!r} (cameras: {', '.join(names)})")
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        self.renderer = mujoco.Renderer(model, height, width)
        self.flags = {mujoco.mjtRndFlag.mjRND_SHADOW: False, mujoco.mjtRndFlag.mjRND_REFLECTION: False}
        low, high = env.observation_space.low[PROPRIO], env.observation_space.high[PROPRIO]
        spaces = {f"image_{self.camera}": gymnasium.spaces.Box(0, 255, (height, width, 3), np.uint8),
                  "state": gymnasium.spaces.Box(low, high, dtype=np.float64)}
        self.env_state = env_state
        if env_state:  # the privileged 39-D state, recorded for --aux-target (module docstring)
            full = env.observation_space
            spaces["env_state"] = gymnasium.spaces.Box(full.low, full.high, dtype=np.float64)
        self.observation_space = gymnasium.spaces.Dict(spaces)
        self.full_state: np.ndarray | None = None  # the 39-D state behind the last observation (for the expert)

    def observation(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        self.full_state = np.asarray(observation)
        self.renderer.update_scene(self.env.unwrapped.data, camera=self.camera)
        for flag, on in self.flags.items():
            self.renderer.scene.flags[flag] = on
        image = self.renderer.render()[::-1, ::-1]  # turned 180 degrees: the corner camera renders upside down
        out = {f"image_{self.camera}": np.ascontiguousarray(image), "state": self.full_state[PROPRIO]}
        if self.env_state:
            out["env_state"] = self.full_state.astype(np.float64)
        return out

    def close(self) -> None:
        self.renderer.close()
        super().close()


def expert(env: gymnasium.Env) -> Any:
    """The scripted policy of the task ``env`` runs, for one episode (``act(obs) -> action``)."""
    from metaworld.policies import ENV_POLICY_MAP  # deferred: an optional dependency

    # Its policies warn at every construction that their gains may exceed the [-1, 1] the env clips to: by design
    warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high", category=UserWarning)

    task = (env.spec.kwargs if env.spec is not None else {}).get("env_name")
    if task not in ENV_POLICY_MAP:
        raise DemoError("--expert metaworld", f"Meta-World has no scripted policy for {task!r}")
    policy = ENV_POLICY_MAP[task]()

    class Expert:
        def act(self, obs: Any) -> np.ndarray:
            state = env.full_state if isinstance(env, CameraObservation) else obs  # from a camera: the privileged state
            return np.asarray(policy.get_action(state), dtype=np.float32)

    return Expert()
