"""The policy interface every learning algorithm plugs into, and the registry by algorithm name.

A policy maps a *normalised* observation history ``obs [B, n_obs, obs_dim]`` (min-max to [-1, 1],
see :mod:`demo.policies.normalizer`) to a *normalised* action chunk ``[B, horizon, action_dim]`` whose
step 0 is the action for the current frame. Everything around it is shared and knows nothing about
the network: the data pipeline (:mod:`demo.training.data`), the training run
(:mod:`demo.training.trainer`), behaviour cloning (:mod:`demo.imitation.bc`), DAgger
(:mod:`demo.imitation.dagger`), checkpoints (:mod:`demo.policies.checkpoint`), execution with chunking and
temporal ensembling (:mod:`demo.policies.actor`), evaluation and plots.

To add a policy (e.g. diffusion, issue #7)::

    @register_policy("diffusion")
    class DiffusionPolicy(Policy):
        Config = DiffusionConfig            # a dataclass of the network's hyperparameters
        def __init__(self, spec: PolicySpec, config: DiffusionConfig): ...
        def loss(self, obs, action, action_pad) -> torch.Tensor: ...
        def predict(self, obs, generator=None) -> torch.Tensor: ...

and add its module to ``POLICY_MODULES`` so ``demo train --algo diffusion`` finds it lazily.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from demo.errors import DemoError


@dataclass(frozen=True)
class PolicySpec:
    """Shapes a policy is built for (everything else is the policy's own Config)."""

    obs_dim: int  # length of the concatenated low-dim observation vector of one frame
    action_dim: int
    n_obs: int = 1  # frames of observation history (current frame last)
    horizon: int = 1  # actions predicted per query (action chunk length)
    # Camera images the policy reads besides the vector: (key, height, width), uint8 RGB. A policy
    # with images is the registered one behind image encoders (demo.policies.visuomotor).
    images: tuple[tuple[str, int, int], ...] = ()
    # An instruction-conditioned policy (demo.policies.instruction): its vocabulary's size and the token
    # ids per instruction; 0 = none.
    vocab: int = 0
    max_tokens: int = 0
    # A conditioning vector per sample (the instruction's) that a policy taking one (``takes_condition``)
    # modulates its hidden layers with (FiLM); 0 = none.
    cond_dim: int = 0
    # Committed actions the policy is told at the start of its chunk (demo.policies.prefix: asynchronous execution
    # under inference delay); 0 = none.
    prefix: int = 0
    # A policy from cameras trained to predict a state from its cameras' features as well (demo train --aux-target:
    # demo.policies.visuomotor): that state's width; 0 = none. Read in training only.
    aux_dim: int = 0
    # How the low-dim vector is laid out, per observation key in its order: (rows, values per row); a key holding one
    # row per object (three cubes' positions, (3, 3)) has 3 rows (ObsSpec.layout). () = not known (a run before it).
    obs_layout: tuple[tuple[int, int], ...] = ()
    # Set by a wrapper for the policy inside it (never recorded; the wrapper derives them again):
    # how one frame's vector splits into tokens (the low-dim part, then each camera's features; () = one
    # token), and the width of the instruction's per-word tokens a policy that ``takes_tokens`` reads (0 = none).
    token_dims: tuple[int, ...] = ()
    text_dim: int = 0
    # A policy from cameras given a condition: whether its encoders FiLM their feature maps by it, and whether
    # its head (when it ``takes_condition``) FiLMs its hidden layers by it (demo.policies.visuomotor).
    film_cameras: bool = False
    film_head: bool = True

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {k: v for k, v in dataclasses.asdict(self).items()
                             if k not in ("images", "obs_layout", "token_dims", "text_dim", "film_cameras", "film_head")}
        if self.images:  # recorded only when set: state runs read as before
            d["images"] = [list(i) for i in self.images]
        if self.obs_layout:
            d["obs_layout"] = [list(row) for row in self.obs_layout]
        if not self.vocab:
            del d["vocab"], d["max_tokens"]
        for key in ("cond_dim", "prefix", "aux_dim"):
            if not d[key]:  # recorded only when set: runs without it read as before
                del d[key]
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "PolicySpec":
        images = tuple((str(k), int(h), int(w)) for k, h, w in d.get("images") or ())
        layout = tuple((int(rows), int(width)) for rows, width in d.get("obs_layout") or ())
        return cls(**{k: int(v) for k, v in d.items() if k not in ("images", "obs_layout")}, images=images,
                   obs_layout=layout)


class Policy(nn.Module):
    """Base class. Subclasses set ``Config`` and implement :meth:`loss` and :meth:`predict`."""

    name: ClassVar[str] = ""
    Config: ClassVar[type] = type(None)
    # Whether the policy takes a conditioning vector (``spec.cond_dim``) beside its observation, as
    # ``{"state": obs, "condition": vector}`` (demo.policies.instruction); else it is appended to the observation.
    takes_condition: ClassVar[bool] = False
    # Whether the policy reads an instruction as its per-word tokens (``spec.text_dim`` wide), as
    # ``{"state": obs, TEXT_TOKENS: [B, L, text_dim], TEXT_PAD: [B, L]}`` (demo.policies.instruction), rather than as one vector.
    takes_tokens: ClassVar[bool] = False

    def __init__(self, spec: PolicySpec, config: Any):
        super().__init__()
        self.spec = spec
        self.config = config

    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        """Scalar training loss for normalised ``obs [B, n_obs, D]``, ``action [B, H, A]``.

        ``action_pad [B, H]`` is True for chunk steps past the episode end (their targets repeat
        the last action); a policy may ignore them, as ACT does.
        """
        raise NotImplementedError

    def fit_actions(self, low: np.ndarray, high: np.ndarray) -> None:
        """Before training: the normalised training actions' min and max per chunk step and dimension
        (``[H, A]``), for a policy whose outputs depend on them (BC's discrete head); default: ignored."""

    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """Normalised action chunk ``[B, H, A]`` for normalised ``obs [B, n_obs, D]``, in eval mode.

        ``generator`` seeds any sampling, so that a rollout is deterministic for its seed.
        """
        raise NotImplementedError


_REGISTRY: dict[str, type[Policy]] = {}

# Algorithm name -> module that registers its policy when imported (so that `demo --help` stays light).
POLICY_MODULES: dict[str, str] = {
    "bc": "demo.policies.mlp",
    "diffusion": "demo.policies.diffusion",
    "flow": "demo.policies.flow",
    "act": "demo.policies.act",
    "transformer": "demo.policies.transformer",
    "ppo": "demo.policies.gaussian",  # the Gaussian policy of PPO, GAIL, AIRL and linear IRL runs
}


def register_policy(name: str):
    """Class decorator: make ``cls`` the policy of algorithm ``name``."""

    def wrap(cls: type[Policy]) -> type[Policy]:
        if not dataclasses.is_dataclass(cls.Config):
            raise TypeError(f"policy {name!r}: Config must be a dataclass")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return wrap


def policy_class(name: str) -> type[Policy]:
    if name not in _REGISTRY and name in POLICY_MODULES:
        importlib.import_module(POLICY_MODULES[name])
    if name not in _REGISTRY:
        known = sorted(set(_REGISTRY) | set(POLICY_MODULES))
        raise DemoError("--algo", f"unknown policy {name!r} (known: {', '.join(known)})")
    return _REGISTRY[name]


def policy_config(name: str, options: dict[str, Any] | None = None) -> Any:
    """The policy's Config dataclass filled from ``options`` (strings are parsed by field type)."""
    cls = policy_class(name)
    fields = {f.name: f for f in dataclasses.fields(cls.Config)}
    values: dict[str, Any] = {}
    for key, value in (options or {}).items():
        key = key.replace("-", "_")
        if key not in fields:
            raise DemoError("--policy-opt", f"policy {name!r} has no option {key!r} (options: {', '.join(fields)})")
        values[key] = _parse(value, fields[key], cls.Config) if isinstance(value, str) else value
    try:
        return cls.Config(**values)
    except (TypeError, ValueError) as exc:
        raise DemoError("--policy-opt", str(exc)) from None


def build_policy(name: str, spec: PolicySpec, config: Any = None, encoder: Any = None, text: Any = None) -> Policy:
    """Policy ``name`` for ``spec``; with camera images in ``spec``, behind image encoders configured
    by ``encoder`` (an :class:`demo.policies.encoders.EncoderConfig`, a dict of its fields, or None);
    with a vocabulary in ``spec``, conditioned on instructions by a text encoder configured by ``text``
    (a :class:`demo.policies.instruction.TextConfig`, a dict of its fields, or None); with ``spec.prefix``,
    told the chunk's committed first actions (:mod:`demo.policies.prefix`), outermost."""
    cls = policy_class(name)
    if config is None or isinstance(config, dict):
        config = policy_config(name, config)
    if spec.prefix:
        from demo.policies.prefix import CommittedPrefixPolicy  # deferred: cycle (it imports this module)

        return CommittedPrefixPolicy(spec, config, lambda inner: build_policy(name, inner, config, encoder, text))
    if spec.vocab:
        from demo.policies.instruction import InstructedPolicy, text_config  # deferred: cycle (it imports this module)

        text = text_config(text)
        film = cls.takes_condition and text.film and (text.film_image_head or not spec.images)
        return InstructedPolicy(spec, config, text, lambda inner: build_policy(name, inner, config, encoder), film,
                                bool(spec.images) and text.film_images, cls.takes_tokens)
    if spec.images:
        from demo.policies.visuomotor import VisuomotorPolicy, encoder_config  # deferred: cycle (visuomotor imports this module)

        return VisuomotorPolicy(spec, config, cls, encoder_config(encoder))
    return cls(spec, config)


def config_to_json(config: Any) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(config).items()}


def parse_flag(text: str) -> bool:
    """An option's on/off value written as text: 1/true/yes or 0/false/no (ValueError otherwise)."""
    if text.lower() not in ("1", "0", "true", "false", "yes", "no"):
        raise ValueError(f"{text!r} is not true or false")
    return text.lower() in ("1", "true", "yes")


def _parse(text: str, field: dataclasses.Field, owner: type) -> Any:
    default = getattr(owner(), field.name)
    try:
        if isinstance(default, bool):
            return parse_flag(text)
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float):
            return float(text)
        if isinstance(default, tuple):
            kind = type(default[0]) if default else int
            return tuple(kind(x) for x in text.split(",") if x.strip())
        return text
    except ValueError:
        raise DemoError("--policy-opt", f"{field.name}={text!r} is not a valid {type(default).__name__}") from None
