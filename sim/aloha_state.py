"""gym-aloha's environments with the simulator's object state in the observation.

Factories for ``--env process:aloha_state:transfer_cube`` and ``process:aloha_state:insertion``
(:mod:`demo.sim.process_env`, with ``--env-opt python=GYM_ALOHA_PYTHON``): they run under
gym-aloha's own interpreter, imported by ``env_worker.py`` from this folder, so it imports nothing of
``demo``. The environment is gym-aloha's, unchanged: its physics, its 14-D joint-position action, its
``agent_pos``, its reward and its success (reward 4). Two things differ, both in what is *observed*:

- ``env_state``: the free objects' poses, ``qpos[16:]`` of gym-aloha's physics (transfer cube: the
  box, 7; insertion: the peg, then the socket, 7 each; position in the world frame, m, then the
  quaternion w, x, y, z): what gym-aloha's task computes as ``env_state`` and its ``Gym`` wrapper drops.
  A scripted expert needs it to be asked what to do in any state; a policy need not read it.
- the cameras: gym-aloha renders three 480x640 views at every step and returns one (``top``); here
  only ``top`` is rendered (``pixels=True``, gym-aloha's resolution), or none (``pixels=False``: the
  expert's and the success measurement's mode, a tenth of the time per step).
"""

from __future__ import annotations

import collections
from typing import Any

IDS = {"transfer_cube": "gym_aloha/AlohaTransferCube-v0", "insertion": "gym_aloha/AlohaInsertion-v0"}
ARM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")  # each ViperX's, in order
# gym-aloha's 14-D action, named as a robot of several arms names it (demo.sim.arms); the gripper is normalised
ACTION_NAMES = tuple(f"{arm}.{joint}" for arm in ("left", "right") for joint in (*ARM_JOINTS, "gripper"))
ACTION_UNITS = tuple("1" if name.endswith("gripper") else "rad" for name in ACTION_NAMES)
GRIPPER_COMMAND = (1.0, 0.0)  # the normalised gripper command at open, at closed (leader capture maps onto it)
ARM_QPOS = 16  # two arms of six joints and two fingers each come first in gym-aloha's qpos


def flag(value: bool | str) -> bool:
    """An ``--env-opt`` flag (it arrives as text): true, or the words false / no / 0."""
    return value if isinstance(value, bool) else str(value).lower() not in ("0", "false", "no")


def transfer_cube(pixels: bool = True, width: int = 640, height: int = 480, max_episode_steps: int | None = None) -> Any:
    """``gym_aloha/AlohaTransferCube-v0`` as described above."""
    return make("transfer_cube", pixels, width, height, max_episode_steps)


def insertion(pixels: bool = True, width: int = 640, height: int = 480, max_episode_steps: int | None = None) -> Any:
    """``gym_aloha/AlohaInsertion-v0`` as described above."""
    return make("insertion", pixels, width, height, max_episode_steps)


def make(task: str, pixels: bool = True, width: int = 640, height: int = 480, max_episode_steps: int | None = None) -> Any:
    """gym-aloha's ``task`` (``transfer_cube`` | ``insertion``) as described above. ``width`` x ``height``:
    the top camera's image (px; gym-aloha's own arguments ``observation_width``/``_height``, its default
    640 x 480); ``max_episode_steps``: None keeps gym-aloha's registered horizon (300 steps at 50 Hz)."""
    import importlib

    import gymnasium
    import numpy as np

    importlib.import_module("gym_aloha")  # registers gym_aloha/*

    if task not in IDS:
        raise ValueError(f"unknown gym-aloha task {task!r} (known: {', '.join(IDS)})")
    pixels = flag(pixels)
    extra = {} if max_episode_steps is None else {"max_episode_steps": int(max_episode_steps)}
    env = gymnasium.make(IDS[task], obs_type="pixels_agent_pos", observation_width=int(width),
                         observation_height=int(height), **extra)
    aloha = env.unwrapped
    inner = aloha._env.task  # the dm_control task: its get_observation renders three cameras
    height, width = aloha.observation_height, aloha.observation_width

    def observe(physics: Any) -> Any:
        obs = collections.OrderedDict(qpos=inner.get_qpos(physics), env_state=physics.data.qpos[ARM_QPOS:].copy())
        if pixels:
            obs["images"] = {"top": physics.render(height=height, width=width, camera_id="top")}
        return obs

    def formatted(raw: Any) -> dict[str, Any]:
        out: dict[str, Any] = {"agent_pos": np.asarray(raw["qpos"], dtype=np.float64),
                               "env_state": np.asarray(raw["env_state"], dtype=np.float64)}
        if pixels:
            out["pixels"] = {"top": raw["images"]["top"].copy()}
        return out

    inner.get_observation = observe
    aloha._format_raw_obs = formatted
    spaces: dict[str, Any] = {
        "agent_pos": aloha.observation_space["agent_pos"],
        "env_state": gymnasium.spaces.Box(-10.0, 10.0, shape=(7 if task == "transfer_cube" else 14,), dtype=np.float64),
    }
    if pixels:
        spaces["pixels"] = aloha.observation_space["pixels"]
    aloha.observation_space = gymnasium.spaces.Dict(spaces)
    aloha.action_names, aloha.action_units = ACTION_NAMES, ACTION_UNITS  # what a store records of the action
    aloha.gripper_command = GRIPPER_COMMAND
    return env
