"""The joint-space PD position layer: motor (torque) actuators become position servos in the MJCF.

`demo` drives every arm joint and the gripper with a *position target* (see :mod:`demo.sim.env`).
A robot whose MJCF drives a joint (or tendon) with a ``<motor>`` gets a PD servo in its place,
written into the spec before it compiles, so MuJoCo applies it at every physics step (no Python per
step; ``implicitfast`` integrates its damping implicitly):

    force = kp (ctrl - L) - kd dL/dt          (L: actuator length, gear * q for a joint)

as a ``general`` actuator with ``gainprm[0] = kp``, ``biasprm[:3] = [0, -kp, -kd]``. The motor's
torque limit is kept: its ``ctrlrange`` times its gain becomes the servo's ``forcerange``, and the
servo's ``ctrlrange`` becomes the target range (the joint range times the gear). Gravity
compensation is as for any robot (the robot config's ``gravcomp``). Why in the MJCF, not a Python
controller: the control loop runs 25 physics steps per action in one ``mj_step(..., nstep)`` call,
a Python PD would have to leave that call every 2 ms (~5x slower), and a compiled servo is the same
in every tool that loads the scene (IK, replay, viewer).

Gains (``pd_kp``, ``pd_kd`` in the robot config, one number or one per actuator, in the actuator's
units: N/m or Nm/rad and N s/m or Nm s/rad). Left out, they follow from the model's inertia at home:
``kp = m w^2``, ``kd = 2 m w`` (critically damped) with ``w = PD_OMEGA`` rad/s and ``m`` the
actuator's inertia with the other joints held, ``m = J M J^T / |J|^4`` (``J`` the actuator's moment
arm row, ``M`` the joint-space inertia matrix incl. armature): for a joint with gear 1, ``M_ii``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from demo.errors import DemoError

PD_OMEGA = 40.0  # rad/s: the default servo bandwidth (6.4 Hz; the control rate is 20 Hz, physics 500 Hz)


def is_position_servo(model: mujoco.MjModel, act: int) -> bool:
    """Whether ``ctrl`` is a position target: fixed gain kp > 0 and affine bias -kp on the length."""
    gain = float(model.actuator_gainprm[act, 0])
    b1 = float(model.actuator_biasprm[act, 1])
    return int(model.actuator_gaintype[act]) == int(mujoco.mjtGain.mjGAIN_FIXED) and b1 < 0 and gain > 0


def is_motor(model: mujoco.MjModel, act: int) -> bool:
    """Whether the actuator is a plain torque source: force = gain * ctrl, no bias, no dynamics."""
    return (
        int(model.actuator_gaintype[act]) == int(mujoco.mjtGain.mjGAIN_FIXED)
        and int(model.actuator_biastype[act]) == int(mujoco.mjtBias.mjBIAS_NONE)
        and int(model.actuator_dyntype[act]) == int(mujoco.mjtDyn.mjDYN_NONE)
        and float(model.actuator_gainprm[act, 0]) != 0.0
    )


def kind_of(model: mujoco.MjModel, act: int) -> str:
    """A word for what an actuator is, for errors."""
    if is_position_servo(model, act):
        return "position servo"
    if is_motor(model, act):
        return "motor"
    if float(model.actuator_biasprm[act, 2]) < 0 and float(model.actuator_biasprm[act, 1]) == 0:
        return "velocity servo"
    if int(model.actuator_dyntype[act]) != int(mujoco.mjtDyn.mjDYN_NONE):
        return "actuator with activation dynamics"
    return "general actuator that is neither a position servo nor a motor"


def actuator_inertia(model: mujoco.MjModel, data: mujoco.MjData, act: int) -> float:
    """``J M J^T / |J|^4``: the inertia an actuator moves with the other joints held (kg or kg m^2)."""
    moment = np.zeros(model.nv)
    # actuator_moment is stored sparse (MuJoCo >= 3.2): rows by actuator, columns in moment_colind.
    start, n = int(data.moment_rowadr[act]), int(data.moment_rownnz[act])
    moment[data.moment_colind[start:start + n]] = data.actuator_moment[start:start + n]
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    jj = float(moment @ moment)
    if jj <= 0.0:
        return 0.0
    return float(moment @ full @ moment) / jj**2


def pd_gains(n: int, kp: Sequence[float], kd: Sequence[float], inertia: Sequence[float], omega: float = PD_OMEGA) -> tuple[np.ndarray, np.ndarray]:
    """Per-actuator (kp, kd): given values (one, or one each) or the inertia-derived defaults."""
    m = np.asarray(inertia, dtype=np.float64)
    kp_out = np.broadcast_to(np.asarray(kp, dtype=np.float64), (n,)).copy() if len(kp) else m * omega**2
    kd_out = np.broadcast_to(np.asarray(kd, dtype=np.float64), (n,)).copy() if len(kd) else 2.0 * m * omega
    return kp_out, kd_out


def add_pd_layer(
    spec: mujoco.MjSpec,
    model: mujoco.MjModel,
    home_qpos: np.ndarray,
    motors: Sequence[int],
    kp: Sequence[float],
    kd: Sequence[float],
    where: Path | None,
) -> None:
    """Turn the motor actuators ``motors`` (ids in ``model``, compiled from ``spec``) into PD servos.

    ``home_qpos``: the configuration whose inertia sets the default gains. ``kp``/``kd``: the
    config's ``pd_kp``/``pd_kd`` (empty: defaults), one number or one per motor.
    """
    if not motors:
        return
    for key, values in (("pd_kp", kp), ("pd_kd", kd)):
        if len(values) not in (0, 1, len(motors)):
            raise DemoError(where, f"'{key}' needs 1 or {len(motors)} numbers (one per motor actuator: "
                                   f"{', '.join(model.actuator(a).name or f'#{a}' for a in motors)})")
    data = mujoco.MjData(model)
    data.qpos[:] = home_qpos
    mujoco.mj_forward(model, data)
    inertia = [actuator_inertia(model, data, a) for a in motors]
    gains, damping = pd_gains(len(motors), kp, kd, inertia)
    for a, k, c in zip(motors, gains, damping):
        name = model.actuator(a).name or f"#{a}"
        if not k > 0 or c < 0:
            raise DemoError(where, f"motor actuator '{name}' gets PD gains kp={k:g}, kd={c:g}; set pd_kp > 0 and pd_kd >= 0 "
                                   "in the config (its joints have no inertia to derive them from)")
        el = spec.actuators[a]  # spec and model list actuators in the same order
        gain = float(model.actuator_gainprm[a, 0])
        if model.actuator_ctrllimited[a]:  # the motor's torque limit, as the servo's force limit
            lo, hi = sorted(gain * float(v) for v in model.actuator_ctrlrange[a])
            if model.actuator_forcelimited[a]:
                lo, hi = max(lo, float(model.actuator_forcerange[a, 0])), min(hi, float(model.actuator_forcerange[a, 1]))
            el.forcerange = [lo, hi]
            el.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        target = _target_range(model, a)
        if target is None:
            el.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        else:
            el.ctrlrange = list(target)
            el.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        el.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        el.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        el.gainprm = [float(k)] + [0.0] * 9
        el.biasprm = [0.0, -float(k), -float(c)] + [0.0] * 7


def _target_range(model: mujoco.MjModel, act: int) -> tuple[float, float] | None:
    """The servo's ctrl range: its joint's range times the gear (None for tendons or unlimited joints)."""
    if int(model.actuator_trntype[act]) != int(mujoco.mjtTrn.mjTRN_JOINT):
        return None
    j = int(model.actuator_trnid[act, 0])
    if not model.jnt_limited[j]:
        return None
    g = float(model.actuator_gear[act, 0])
    lo, hi = sorted(g * float(v) for v in model.jnt_range[j])
    return lo, hi
