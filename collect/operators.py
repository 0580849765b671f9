"""Simulated operator profiles: how a person of a given skill would drive the scripted expert.

Mixed-quality datasets (like robomimic's multi-human data) come from people who hesitate, jitter,
switch strategies and sometimes fail. An :class:`Operator` wraps the state-feedback expert and turns
its clean command into what such a person would have sent. For these episodes the recorded action is
what the operator sent (a human dataset has no clean label); DART-style ``--noise`` is different:
there the clean expert action is the label and only the executed action is perturbed.

Per-episode draws (all from the episode's rng, so a seed reproduces the episode):

========  =========  ==============  =============  ===================  ==========================
profile   jitter     hand wander     pauses         strategy             failure (freeze / drop)
========  =========  ==============  =============  ===================  ==========================
expert    0          0               none           default              never
good      0.002 rad  4 mm            rare, short    varied per episode   2%
okay      0.008 rad  7 mm            idle start     varied per episode   10%
poor      0.015 rad  10 mm           long, often    varied per episode   35%
========  =========  ==============  =============  ===================  ==========================

Jitter is white noise on the arm joint targets (jerky motion). The hand wander is a slow, smooth
offset (two sinusoids of 0.1-0.4 Hz per axis, random phases) added to every position the expert
aims at, so the hand drifts off the ideal path while the expert's feedback keeps following it; the
same offset on the joint targets would outrun the expert's correction and make every episode fail.
Wander is smooth on purpose: it makes episodes differ (inconsistent), jitter makes them jerky. A pause holds the
last command for a while (idle frames); a failure either freezes the operator for the rest of the
episode or opens the gripper early.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demo.errors import DemoError

PROFILE_NAMES = ("expert", "good", "okay", "poor")


@dataclass(frozen=True)
class Profile:
    name: str
    jitter_rad: float  # std of white noise on arm joint targets per control step
    wander_m: float  # amplitude (std) of the slow wander of the expert's aim point (m, base frame)
    idle_start_s: tuple[float, float]  # range of the idle time before the operator starts
    pause_rate_hz: float  # expected mid-episode pauses per second
    pause_s: tuple[float, float]  # range of a pause's duration
    speed: tuple[float, float]  # range of the expert speed scale
    vary_strategy: bool  # let the expert pick strategy variations from the rng
    failure_prob: float  # chance that this episode contains an operator failure


PROFILES: dict[str, Profile] = {
    "expert": Profile("expert", 0.0, 0.0, (0.0, 0.0), 0.0, (0.0, 0.0), (1.0, 1.0), False, 0.0),
    "good": Profile("good", 0.002, 0.004, (0.0, 0.3), 0.02, (0.2, 0.5), (0.85, 1.0), True, 0.02),
    "okay": Profile("okay", 0.008, 0.007, (0.5, 1.5), 0.08, (0.3, 1.0), (0.7, 1.0), True, 0.10),
    "poor": Profile("poor", 0.015, 0.010, (1.0, 3.0), 0.2, (0.5, 2.0), (0.5, 1.0), True, 0.35),
}


def get_profile(name: str) -> Profile:
    if name not in PROFILES:
        raise DemoError("--operator", f"unknown operator profile {name!r} (choose from {', '.join(PROFILE_NAMES)})")
    return PROFILES[name]


class Operator:
    """Turns the expert's clean joint-position command into a simulated person's command.

    ``n_arm`` is the number of arm joints at the front of the action; the remaining entries are the
    gripper command, which only a failure ("drop") changes.
    """

    def __init__(self, profile: Profile, rng: np.random.Generator, fps: float, horizon: int, n_arm: int):
        self.profile = profile
        self.rng = rng
        self.fps = fps
        self.n_arm = n_arm
        self.speed = float(rng.uniform(*profile.speed))
        self.idle_steps = int(round(rng.uniform(*profile.idle_start_s) * fps))
        self.fails = bool(rng.random() < profile.failure_prob)
        self.failure_kind = str(rng.choice(["freeze", "drop"])) if self.fails else ""
        self.failure_step = int(rng.integers(self.idle_steps + horizon // 4, max(self.idle_steps + horizon // 4 + 1, horizon * 3 // 4)))
        self._wander_hz = rng.uniform(0.1, 0.4, size=(2, 3))
        self._wander_phase = rng.uniform(0.0, 2 * np.pi, size=(2, 3))
        self._step = 0
        self._pause_left = 0
        self._held: np.ndarray | None = None

    @property
    def expert_style(self) -> dict:
        return {"speed": self.speed, "vary": self.profile.vary_strategy}

    def steer(self, expert: object) -> None:
        """Move the expert's aim point one step along the hand's random walk (call before ``act``)."""
        if self.profile.wander_m > 0:
            t = self._step / self.fps
            waves = np.sin(2 * np.pi * self._wander_hz * t + self._wander_phase).sum(axis=0)
            expert.aim_offset = self.profile.wander_m * waves  # each sinusoid has std 1/sqrt(2)
            self._step += 1

    def command(self, step: int, clean: np.ndarray, hold: np.ndarray) -> np.ndarray:
        """The command sent at control ``step``: ``clean`` from the expert, ``hold`` = keep still."""
        p = self.profile
        if step < self.idle_steps:
            return hold.copy()
        if self.fails and step >= self.failure_step:
            if self.failure_kind == "freeze":
                if self._held is None:
                    self._held = hold.copy()
                return self._held.copy()
            out = clean.copy()
            out[self.n_arm :] = 0.0  # drop: open the gripper, whatever the expert says
            return out
        if self._pause_left > 0:
            self._pause_left -= 1
            return self._held.copy() if self._held is not None else hold.copy()
        if p.pause_rate_hz > 0 and self.rng.random() < p.pause_rate_hz / self.fps:
            self._pause_left = int(round(self.rng.uniform(*p.pause_s) * self.fps))
            self._held = hold.copy()
            return self._held.copy()
        self._held = None
        out = clean.copy()
        if p.jitter_rad > 0:
            out[: self.n_arm] += self.rng.normal(0.0, p.jitter_rad, self.n_arm)
        return out
