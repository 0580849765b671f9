"""State perturbation with expert labels: training data from perturbed states the expert labels.

``demo train DATA --algo perturb --task T --rounds R --episodes-per-round K [--algo-opt sigma=0.05]``
runs DAgger's loop (:func:`demo.imitation.dagger.train_dagger`) with this file's :class:`Perturb`
rounds. Each round's episodes follow the expert from new initial states; at every control step the
state is copied, the copy's arm joints are displaced by ``N(0, sigma^2)`` rad each (within the joint
limits), the expert is asked what to do *there*, and that perturbed frame with the expert's answer is
recorded; the expert then acts from the unperturbed state, so the trajectory itself is clean. The
recorded episodes therefore hold the states a learner's small errors lead to, each with the action
that recovers from it, without the learner acting and without noise in the executed trajectory
(unlike DART, whose noise drives the trajectory).

A displaced arm that holds an object would leave it behind, inside or away from the fingers: an
object a finger touches moves rigidly with the end-effector (its pose relative to the EE site is
kept). A perturbation that leaves two bodies interpenetrating by more than :data:`PENETRATION` is
drawn again (up to ``tries`` times; then the unperturbed frame is recorded with the expert's label).

Every recorded frame is a label (``info.labelled``). The frames of one episode are independent
perturbations, not a trajectory: train a single-step learner on them (DAgger's default, ``--chunk 1``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np

from demo.sim.geometry import mat_to_quat, quat_to_mat
from demo.sim.rollout import Episode, StepCommand, rollout
from demo.imitation.dagger import Family, episode_record

PENETRATION = 0.003  # m: deeper contacts make a perturbed state physically impossible


def held_joints(env: Any) -> list[int]:
    """``qpos`` addresses of the free joints of the bodies a finger touches (the objects in hand)."""
    m, d = env.model, env.data
    if d.ncon == 0:
        return []
    bodies = m.geom_bodyid[d.contact.geom]  # [ncon, 2]
    fingers = np.isin(bodies, env.finger_bodies)
    touched = np.r_[bodies[fingers[:, 0], 1], bodies[fingers[:, 1], 0]]
    out = []
    for b in sorted(set(touched.tolist())):
        adr = int(m.body_jntadr[b])
        if m.body_jntnum[b] == 1 and m.jnt_type[adr] == mujoco.mjtJoint.mjJNT_FREE:
            out.append(int(m.jnt_qposadr[adr]))
    return out


def perturb_state(env: Any, rng: np.random.Generator, sigma: float) -> bool:
    """Displace the arm's joints by ``N(0, sigma^2)`` rad (clipped to their limits), carrying any held
    object along with the end-effector; False (state left displaced: restore it) if bodies then
    interpenetrate by more than :data:`PENETRATION`."""
    m, d = env.model, env.data
    held = held_joints(env)
    site = env.ee_site
    pos0, rot0 = d.site_xpos[site].copy(), d.site_xmat[site].reshape(3, 3).copy()
    relative = [(a, rot0.T @ (d.qpos[a : a + 3] - pos0), rot0.T @ quat_to_mat(d.qpos[a + 3 : a + 7])) for a in held]
    limits = m.jnt_range[[m.joint(j).id for j in env.robot.arm_joints]]
    q = d.qpos[env.arm_qadr] + rng.normal(0.0, sigma, len(env.arm_qadr))
    d.qpos[env.arm_qadr] = np.clip(q, limits[:, 0], limits[:, 1])
    mujoco.mj_kinematics(m, d)
    pos1, rot1 = d.site_xpos[site].copy(), d.site_xmat[site].reshape(3, 3).copy()
    for a, p, r in relative:
        d.qpos[a : a + 3] = pos1 + rot1 @ p
        d.qpos[a + 3 : a + 7] = mat_to_quat(rot1 @ r)
    mujoco.mj_forward(m, d)
    return d.ncon == 0 or float(d.contact.dist.min()) >= -PENETRATION


@dataclass
class PerturbEpisodes:
    """One clean expert episode recorded as perturbed, expert-labelled frames (module docstring)."""

    sigma: float
    tries: int = 5

    def __call__(self, env: Any, actor: Any, seed: int) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        env.reset(seed)
        driver = env.expert(rng=np.random.default_rng([seed, 2]))
        labeller = env.expert(rng=np.random.default_rng([seed, 2]))  # asked at perturbed states only
        rng = np.random.default_rng([seed, 6])
        steps: list[tuple[dict[str, np.ndarray], StepCommand]] = []

        def act(env: Any, frame: dict[str, np.ndarray], t: int) -> StepCommand:
            action = np.asarray(driver.act(env), dtype=np.float32)
            own = StepCommand(action, action, np.asarray(driver.ee_target, np.float32))
            state = env.get_state()
            recorded = (frame, own)
            for _ in range(self.tries):
                ok = perturb_state(env, rng, self.sigma)
                if ok:
                    label = np.asarray(labeller.act(env), dtype=np.float32)
                    recorded = (env.frame(), StepCommand(label, label, np.asarray(labeller.ee_target, np.float32)))
                env.set_state(state)
                if ok:
                    break
            steps.append(recorded)
            return own

        episode = rollout(env, seed, act, reset=False, record=False)
        data = {k: np.array([f[k] for f, _ in steps]) for k in steps[0][0]}
        data.update({"action": np.array([c.label for _, c in steps]), "info.executed_action": np.array([c.executed for _, c in steps]),
                     "info.ee_target": np.array([c.ee_target for _, c in steps])})
        flags = [True] * len(steps)
        record = Episode(data, episode.success, episode.length, episode.first_success_step, episode.failure)
        return episode_record(record, seed, flags, flags, 1.0, source="perturb")


@dataclass
class Perturb(Family):
    """State perturbation's rounds (module docstring); ``sigma``: std of the arm joint displacement (rad)."""

    name: str = "perturb"
    OPTIONS: ClassVar[tuple[str, ...]] = ("sigma", "tries")
    CHUNK_LABELS: ClassVar[bool] = False  # its own labelling: single-step labels
    FOREIGN: ClassVar[bool] = False  # needs the simulator's state and the task's own expert
    sigma: float = 0.05
    tries: int = 5

    def episodes(self, run: Any, store: Any, env: Any, r: int, beta: float, gate: float | None) -> PerturbEpisodes:
        return PerturbEpisodes(self.sigma, self.tries)

    def to_json(self) -> dict[str, Any]:
        return {"sigma": self.sigma, "tries": self.tries}
