"""Gymnasium spaces of a task environment: observations from the store's features, actions from the
action format.

Observations: a ``Dict`` over the env's ``obs.*`` features (:attr:`demo.sim.env.Env.features`), so the
keys and dtypes are those a store collected from the same env records, each low-dim feature flattened to
one dimension (a store's ``obs.object_pos`` of shape (n, 3) is (3 n,) here, as trajectory and RL libraries
take it): low-dim state (float32, m, rad, rad/s, quaternions wxyz in the robot base frame) bounded where
the bound is physical (:func:`feature_bounds`: joint positions by the joints' limits, the gripper's measured
closedness in [0, 1] widened by ``GRIPPER_SLACK`` (fingers pressed shut or spread by contact overshoot
their open and closed positions slightly: -0.0003 and 1.004 seen on the built-in arm), quaternions in [-1, 1], positions within +-``REACH`` m of the base), unbounded otherwise
(velocities); camera images ``obs.image_<camera>`` as uint8 ``Box`` es in [0, 255] of shape
[height, width, 3].

Actions: a float32 ``Box`` of the format's dimension (:mod:`demo.convert.representations` defines
every number). Its bounds are the range a policy is meant to act in, and the one random exploration
samples from; the env executes what it is given (the simulator clips joint targets to the actuators'
ranges). The gripper is a closedness in [0, 1] in every format; the rest:

- ``joint_pos``: the arm joints' limits (rad);
- ``joint_vel``: +-``JOINT_SPEED`` rad/s;
- ``ee_abs``: position +-``REACH`` m (base frame), rotation within its form's range (euler and rotvec
  +-pi rad, quat and rot6d +-1);
- ``ee_delta``, ``ee7``: position +-``EE_STEP`` m and rotation +-``ROT_STEP`` rad per control step
  (rot6d +-1). The experts move at most 0.35 m/s and 2 rad/s, 0.0175 m and 0.1 rad per step at 20 Hz.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from gymnasium import spaces

from demo.convert.representations import ActionFormat
from demo.store import FeatureSpec

JOINT_SPEED = 2 * math.pi  # rad/s
GRIPPER_SLACK = 0.05  # of the measured gripper closedness, beyond [0, 1] (module docstring)
REACH = 1.5  # m, |x|, |y|, |z| of an absolute EE position in the base frame
EE_STEP = 0.05  # m per control step (1 m/s at 20 Hz)
ROT_STEP = 0.5  # rad per control step (10 rad/s at 20 Hz)
_ROTATION_BOUND = {"euler": math.pi, "rotvec": math.pi, "quat": 1.0, "rot6d": 1.0}


def feature_bounds(key: str, size: int, joint_limits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Physical bounds of a flattened low-dim feature (module docstring); +-inf where none is known."""
    low, high = np.full(size, -np.inf), np.full(size, np.inf)
    if key == "obs.joint_pos" and size == len(joint_limits):
        low, high = joint_limits[:, 0].copy(), joint_limits[:, 1].copy()
    elif key == "obs.gripper":
        low[:], high[:] = -GRIPPER_SLACK, 1.0 + GRIPPER_SLACK
    elif key.endswith("_quat"):
        low[:], high[:] = -1.0, 1.0
    elif key.endswith("_pos"):
        low[:], high[:] = -REACH, REACH
    return low, high


def feature_space(key: str, feature: FeatureSpec, joint_limits: np.ndarray, flat: bool = True) -> spaces.Box:
    """The space of one per-frame feature: uint8 images in [0, 255] as they are; anything else bounded by
    :func:`feature_bounds`, flat (or in the store's shape: ``flat=False``)."""
    dtype = np.dtype(feature.dtype)
    if dtype == np.uint8:
        return spaces.Box(0, 255, shape=feature.shape, dtype=np.uint8)
    low, high = feature_bounds(key, int(np.prod(feature.shape)), joint_limits)
    shape = low.shape if flat else feature.shape
    return spaces.Box(low.reshape(shape).astype(dtype), high.reshape(shape).astype(dtype), dtype=dtype)


def observation_space(features: Mapping[str, FeatureSpec], keys: Sequence[str], joint_limits: np.ndarray,
                      flat: bool = True) -> spaces.Dict:
    """A ``Dict`` of ``keys`` (store feature names, e.g. ``obs.joint_pos``); ``joint_limits`` [n_arm, 2] (rad)."""
    return spaces.Dict({k: feature_space(k, features[k], joint_limits, flat) for k in keys})


def action_space(fmt: ActionFormat, joint_limits: np.ndarray) -> spaces.Box:
    """The ``Box`` of ``fmt`` (module docstring); ``joint_limits`` [n_arm, 2] (rad) bound ``joint_pos``."""
    if fmt.rep.space == "joint":
        if fmt.rep.delta:
            low = np.full(len(fmt.joint_names), -JOINT_SPEED)
            high = -low
        else:
            low, high = joint_limits[:, 0], joint_limits[:, 1]
    else:
        assert fmt.rotation is not None
        rot_bound = _ROTATION_BOUND[fmt.rotation]
        if fmt.rep.delta and fmt.rotation != "rot6d":
            rot_bound = ROT_STEP
        pos_bound = EE_STEP if fmt.rep.delta else REACH
        high = np.r_[np.full(3, pos_bound), np.full(fmt.rot_dim, rot_bound)]
        low = -high
    return spaces.Box(np.r_[low, 0.0].astype(np.float32), np.r_[high, 1.0].astype(np.float32), dtype=np.float32)
