"""Running a trained policy step by step: observation history, action chunks, temporal ensembling.

This is the one place where a policy meets an environment, used by evaluation, by DAgger's
rollouts and by periodic evaluation during training, so that all of them execute the policy exactly
as it was trained:

- **observation history**: the last ``n_obs`` frames, the first frame repeated at the episode
  start (the same edge padding as :class:`demo.store.WindowSampler` in training), camera images
  alongside the low-dim vector for a visuomotor policy;
- **chunking**: a query returns ``horizon`` actions, step 0 for the current frame; a new query is
  made every ``execute`` steps (receding horizon);
- **temporal ensembling** (ACT, Zhao et al. 2023): with ``ensemble = m`` the action for step ``t``
  is the weighted mean over every stored chunk that covers ``t``, weight ``exp(-m * i)`` with
  ``i = 0`` for the oldest chunk; ``ensemble = None`` executes the newest chunk only;
- **coherent sampling** (the backward coherence of Bidirectional Decoding, Liu et al. 2024): with
  ``candidates = K > 1`` a query draws K chunks from a sampling policy (one batch) and keeps the one
  closest to the newest stored chunk over the steps both cover (mean squared distance in the
  normalised action units). A multimodal policy then stays on the mode it chose, so ensembling
  averages chunks of one mode instead of two. The first query of an episode keeps the first draw.

A residual (:mod:`demo.policies.residual`, trained by RL on a frozen policy) adds its correction to the
merged action before the binary commands are rounded.

An instruction-conditioned policy (:mod:`demo.policies.instruction`) is told its episode's
instruction at :meth:`PolicyActor.reset`: the one set on the actor (``demo eval --instruction``), else
the environment's own (``env.instruction``: a task set's member's, e.g. Meta-World's task as a sentence).

Actions leave in the policy's action representation and go through an action adapter
(:mod:`demo.policies.actions`) to become what the environment takes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from demo.errors import DemoError
from demo.policies.actions import ActionAdapter
from demo.policies.instruction import INSTRUCTION, InstructionTokenizer
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import STATE, ObsSpec
from demo.policies.policy import Policy
from demo.policies.prefix import PREFIX, PREFIX_STEPS
from demo.policies.relative import RelativeActions
from demo.policies.residual import Residual


@dataclass
class ExecConfig:
    """How chunks are executed (recorded in the run; ``demo eval`` may override it)."""

    execute: int = 1  # actions executed from each chunk before the next query
    ensemble: float | None = None  # temporal ensembling decay m (ACT uses 0.01); None = off
    # Action dims executed as binary commands (>= 0.5 -> 1, else 0), e.g. a gripper whose labels are
    # open/closed: a regressed 0.07 leaves the fingers a little closed, the measured closedness then
    # reads as "closing" and the policy holds still, waiting for a grasp it never makes.
    binary: tuple[int, ...] = ()
    candidates: int = 1  # chunks drawn per query, the most coherent kept (module docstring); 1 = off

    def check(self, horizon: int) -> None:
        if not 1 <= self.execute <= horizon:
            raise ValueError(f"execute must lie in [1, chunk={horizon}], got {self.execute}")
        if self.ensemble is not None and self.ensemble < 0:
            raise ValueError(f"the ensembling decay must be >= 0, got {self.ensemble}")
        if self.candidates < 1:
            raise ValueError(f"candidates must be at least 1, got {self.candidates}")

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"execute": self.execute, "ensemble": self.ensemble}
        if self.binary:  # recorded only when set: runs without it read as before
            d["binary"] = list(self.binary)
        if self.candidates > 1:
            d["candidates"] = self.candidates
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ExecConfig":
        e = d.get("ensemble")
        return cls(execute=int(d.get("execute", 1)), ensemble=None if e is None else float(e),
                   binary=tuple(int(i) for i in d.get("binary") or ()), candidates=int(d.get("candidates", 1)))


class PolicyActor:
    """Stateful executor of one policy; call :meth:`reset` at every episode start."""

    def __init__(
        self,
        policy: Policy,
        obs_spec: ObsSpec,
        obs_norm: MinMaxNormalizer,
        action_norm: MinMaxNormalizer,
        execution: ExecConfig,
        adapter: ActionAdapter | None = None,
        relative: RelativeActions | None = None,
        tokenizer: InstructionTokenizer | None = None,
        residual: Residual | None = None,
    ):
        execution.check(policy.spec.horizon)
        self.policy = policy.eval()
        self.obs_spec, self.obs_norm, self.action_norm = obs_spec, obs_norm, action_norm
        self.execution = execution
        self.adapter = adapter
        self.relative = relative
        self.tokenizer = tokenizer
        self.residual = residual  # a correction added to every action (demo.policies.residual)
        self.instruction: str | None = None  # told to every episode (else the environment's own)
        self.tokens: np.ndarray | None = None  # [1, max_tokens] of the episode's instruction
        self.n_obs, self.horizon = policy.spec.n_obs, policy.spec.horizon
        self.device = next(policy.parameters(), torch.empty(0)).device
        self.generator = torch.Generator(device=self.device)
        self.queries = 0
        self.reset(0)

    def reset(self, seed: int, env: Any = None) -> None:
        """Start an episode: clear history and chunks, seed the policy's sampling from ``seed``."""
        if self.adapter is not None and env is not None:
            self.adapter.reset(env)
        # the episode's instruction: the one set on the actor, else the environment's own ("" for none)
        self.told: str = self.instruction or getattr(env, "instruction", None) or ""
        if self.tokenizer is not None:
            if env is not None and not self.told:
                raise DemoError("--instruction", "the policy follows instructions and this environment gives none: "
                                                 "tell it one")
            self.tokens = self.tokenizer.encode([self.told])
        self.history: deque[np.ndarray] = deque(maxlen=self.n_obs)
        self.images: dict[str, deque[np.ndarray]] = {k: deque(maxlen=self.n_obs) for k in self.obs_spec.images}
        self.chunks: deque[tuple[int, np.ndarray]] = deque()  # (first step, [H, A] raw actions)
        self.t = 0
        self.last_query = -(10**9)
        self.generator.manual_seed(int(seed) & 0x7FFF_FFFF_FFFF_FFFF)

    def _query(self, frame: dict[str, np.ndarray], committed: np.ndarray | None = None) -> np.ndarray:
        k = self.execution.candidates
        state = np.clip(self.obs_norm.normalize(np.stack(self.history)), -OBS_CLIP, OBS_CLIP)[None]  # [1, n_obs, D]
        obs: torch.Tensor | dict[str, torch.Tensor] = torch.from_numpy(np.repeat(state, k, axis=0)).to(self.device)
        if self.images or self.tokens is not None or committed is not None:
            obs = {STATE: obs, **{key: torch.from_numpy(np.repeat(np.stack(h)[None], k, axis=0)).to(self.device)
                                  for key, h in self.images.items()}}
        if self.tokens is not None:
            obs[INSTRUCTION] = torch.from_numpy(np.repeat(self.tokens, k, axis=0)).to(self.device)
        if committed is not None:  # the policy's own representation: relative to this frame, normalised
            if self.relative is not None:
                committed = committed - self.relative.base_frame(frame, committed.shape[1])
            given = np.zeros((self.policy.spec.prefix, committed.shape[1]), np.float32)
            given[: len(committed)] = self.action_norm.normalize(committed)
            obs[PREFIX] = torch.from_numpy(np.repeat(given[None], k, axis=0)).to(self.device)
            obs[PREFIX_STEPS] = torch.full((k,), len(committed), dtype=torch.long, device=self.device)
        with torch.inference_mode():
            chunks = self.action_norm.unnormalize(self.policy.predict(obs, generator=self.generator).float().cpu().numpy())
        self.queries += 1
        if self.relative is not None:
            chunks = chunks + self.relative.base_frame(frame, chunks.shape[2])
        chosen = 0
        if k > 1 and self.chunks:
            # Backward coherence: the draw closest to the newest stored chunk where both say something,
            # in normalised action units (the normaliser's per-dimension scale).
            start, previous = self.chunks[-1]
            overlap = previous[self.t - start:]  # its actions for steps t .. start + H - 1
            gap = (chunks[:, : len(overlap)] - overlap) * self.action_norm.scale
            chosen = int(np.argmin((gap**2).mean(axis=(1, 2))))
        return chunks[chosen]

    def _observe(self, frame: dict[str, np.ndarray]) -> None:
        """Add ``frame`` to the observation history (the first fills it)."""
        obs = self.obs_spec.vector(frame)
        if not self.history:
            self.history.extend([obs] * self.n_obs)
            for key, h in self.images.items():
                h.extend([frame[key]] * self.n_obs)
        else:
            self.history.append(obs)
            for key, h in self.images.items():
                h.append(frame[key])

    def chunk(self, frame: dict[str, np.ndarray], prefix: np.ndarray | None = None) -> np.ndarray:
        """``[H, A]``: the policy's chunk from this frame (its own representation, absolute), for an executor
        that runs chunks itself (a robot-side client of :mod:`demo.deploy`); ``frame`` joins the history.

        ``prefix [d, A]``: the actions the executor has already committed to for this frame's step and the
        ``d - 1`` after it (absolute). A policy trained to continue them (:mod:`demo.policies.prefix`) is told
        up to its ``spec.prefix`` of them and its chunk starts with them; another ignores them."""
        committed = None
        if prefix is not None:
            prefix = np.asarray(prefix, np.float32)
            width = self.action_norm.dim
            if prefix.ndim != 2 or prefix.shape[1] != width or not np.isfinite(prefix).all():
                raise ValueError(f"the prefix must be finite [steps, {width}] actions, got shape {tuple(prefix.shape)} "
                                 f"({prefix.shape[-1] if prefix.ndim else 0} action dims)")
            allowed = self.policy.spec.prefix
            committed = prefix[:allowed] if allowed and len(prefix) else None
        self._observe(frame)
        chunk = self._query(frame, committed).astype(np.float32)
        if committed is not None:
            chunk[: len(committed)] = committed
        return chunk

    def policy_action(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        """The policy's action for this frame (its own representation); advances one step."""
        base = self.base_action(frame)
        if self.residual is not None:
            base = base + self.residual.correction(frame, base)
        return self.finish(base)

    def base_action(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        """The policy's own action for this frame, chunks merged, before a residual's correction and the
        binary commands (:meth:`finish`); advances one step."""
        self._observe(frame)
        t = self.t
        if t - self.last_query >= self.execution.execute:
            self.chunks.append((t, self._query(frame)))
            self.last_query = t
        while self.chunks and self.chunks[0][0] + self.horizon <= t:
            self.chunks.popleft()
        if self.execution.ensemble is None:
            start, chunk = self.chunks[-1]
            action = chunk[t - start]
        else:
            # Oldest first: weight exp(-m * i) favours older predictions, as in ACT.
            acts = np.stack([chunk[t - start] for start, chunk in self.chunks])
            w = np.exp(-self.execution.ensemble * np.arange(len(acts)))
            action = (w[:, None] * acts).sum(axis=0) / w.sum()
        self.t += 1
        return action.astype(np.float32)

    def finish(self, action: np.ndarray) -> np.ndarray:
        """An action as it is executed: the binary dims (``ExecConfig.binary``) made 0 or 1."""
        action = np.asarray(action, np.float32).copy()
        if self.execution.binary:
            dims = list(self.execution.binary)
            action[dims] = (action[dims] >= 0.5).astype(np.float32)
        return action

    def act(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        """The action to send to the environment (through the adapter)."""
        action = self.policy_action(frame)
        return self.adapter(action) if self.adapter is not None else action

