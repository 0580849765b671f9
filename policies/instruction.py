"""Instruction-conditioned policies: one policy for many tasks, told what to do in words.

An episode's instruction (the store's ``instruction`` column, :mod:`demo.store.instructions`) reaches the policy as token ids, and every
piece here is trained from scratch on this machine (nothing is downloaded):

- :class:`InstructionTokenizer`: a word-level vocabulary (HuggingFace ``tokenizers``' ``WordLevel``,
  lower-cased, accents stripped, split on whitespace and punctuation) trained on the training
  instructions; a word it never saw becomes ``[UNK]``, never an index error. It is saved as JSON in
  the run record (``tokenizers`` parses it in Rust: no pickle, nothing executed).
- :class:`TextEncoder`: token embeddings and learned positions, a small pre-norm transformer encoder,
  and the mean over the instruction's tokens (padding masked): one vector per instruction.
- A pretrained encoder by path (``--text-opt init=RUN``, :func:`pretrained_text`): the tokenizer and text
  encoder of an instruction-conditioned run trained before (on other tasks, other data) start a new run,
  fine-tuned or kept as they are (``freeze=true``); read from that run's files, nothing fetched. Its
  vocabulary stays: a word it never saw is ``[UNK]``.
- :class:`InstructedPolicy`: any policy told the instruction's vector, trained end to end on the
  wrapped policy's own loss. BC's MLP on state takes it by FiLM (RT-1's conditioning): every hidden
  layer's activations scaled and shifted by a linear function of it, so that the words can *select*
  what the layer passes on (which of three cubes to go to); behind camera encoders it does so with
  ``film_image_head``. Other policies (diffusion, flow, ACT, and BC from cameras by default) get it appended
  to the low-dim observation of every history frame; a policy from cameras with ``film_images`` also FiLMs
  each camera's feature maps by it (RT-1's image encoder, :class:`demo.policies.encoders.CameraEncoder`).

Observations reach it as a dict: the wrapped policy's observation (the low-dim vector, or the
visuomotor dict) plus :data:`INSTRUCTION` -> ``[B, max_tokens]`` int64 token ids (0-padded).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from demo.policies.observation import STATE
from demo.policies.policy import Policy, PolicySpec, parse_flag

INSTRUCTION = "instruction"  # the token ids' entry in an observation dict
CONDITION = "condition"  # the instruction's vector, for a policy that takes it by FiLM (Policy.takes_condition)
TEXT_TOKENS, TEXT_PAD = "text_tokens", "text_pad"  # its per-word outputs and padding, for a policy that takes_tokens
PAD, UNKNOWN = "[PAD]", "[UNK]"  # token ids 0 and 1


class InstructionTokenizer:
    """Words to token ids with a vocabulary trained on the training instructions (module docstring)."""

    def __init__(self, tokenizer: Any, max_tokens: int):
        self.tokenizer = tokenizer
        self.max_tokens = int(max_tokens)

    @classmethod
    def train(cls, instructions: Sequence[str]) -> "InstructionTokenizer":
        """A vocabulary of every word of ``instructions``; ``max_tokens`` the longest one's length."""
        from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, trainers  # deferred: training only

        tokenizer = Tokenizer(models.WordLevel(unk_token=UNKNOWN))
        tokenizer.normalizer = normalizers.Sequence([normalizers.NFD(), normalizers.Lowercase(), normalizers.StripAccents()])
        tokenizer.pre_tokenizer = pre_tokenizers.Whitespace()
        tokenizer.train_from_iterator(list(instructions), trainers.WordLevelTrainer(special_tokens=[PAD, UNKNOWN]))
        longest = max((len(tokenizer.encode(text).ids) for text in instructions), default=1)
        return cls(tokenizer, max(1, longest))

    @property
    def vocab_size(self) -> int:
        return int(self.tokenizer.get_vocab_size())

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """``[len(texts), max_tokens]`` int64 ids, 0-padded; words past ``max_tokens`` are cut (an
        instruction longer than any trained on)."""
        out = np.zeros((len(texts), self.max_tokens), np.int64)
        for row, text in enumerate(texts):
            ids = self.tokenizer.encode(str(text)).ids[: self.max_tokens]
            out[row, : len(ids)] = ids
        return out

    def unknown_words(self, text: str) -> list[str]:
        """The words of ``text`` outside the vocabulary (each becomes ``[UNK]``)."""
        text = str(text)
        encoding = self.tokenizer.encode(text)
        return [text[start:stop] for (start, stop), i in zip(encoding.offsets, encoding.ids) if i == 1]

    def to_json(self) -> dict[str, Any]:
        return {"tokenizer": json.loads(self.tokenizer.to_str()), "max_tokens": self.max_tokens}

    @classmethod
    def from_json(cls, record: dict[str, Any]) -> "InstructionTokenizer":
        """From a run record (untrusted: a malformed one raises ValueError)."""
        from tokenizers import Tokenizer  # deferred: only for instruction-conditioned runs

        try:
            tokenizer = Tokenizer.from_str(json.dumps(record["tokenizer"]))
        except Exception as exc:  # noqa: BLE001 - tokenizers raises a bare Exception on malformed JSON
            raise ValueError(f"the instruction tokenizer does not read ({str(exc)[:120]})") from None
        max_tokens = int(record["max_tokens"])
        if not 1 <= max_tokens <= 1024:
            raise ValueError(f"the instruction tokenizer's max_tokens must lie in [1, 1024], got {max_tokens}")
        return cls(tokenizer, max_tokens)


@dataclass
class TextConfig:
    """The instruction encoder (``demo train --text-opt KEY=VALUE``)."""

    dim: int = 64  # width of the token embeddings and of the instruction vector
    layers: int = 1  # transformer encoder layers over the tokens (0: mean of the embeddings)
    heads: int = 4
    dropout: float = 0.0
    # A policy that takes a condition (BC's MLP on state) is told the vector by FiLM in its hidden layers;
    # false: appended to its observation, as every other policy is
    film: bool = True
    # A policy from cameras: FiLM its image encoders' feature maps by the vector too (RT-1's design)
    film_images: bool = False
    # A policy from cameras whose head takes a condition (BC's MLP): with film, FiLM the head's hidden layers by
    # the vector as on state; false: the vector is appended to the proprioception. Off by default: on pick's
    # coloured cubes from two cameras it made no difference (1/100 against 6/100, both ignoring the words)
    film_image_head: bool = False
    # A pretrained encoder on disk: the run directory of an instruction-conditioned policy, whose tokenizer
    # and text encoder (its dim, layers and heads too) start this one (:func:`pretrained_text`)
    init: str = ""
    freeze: bool = False  # with init: keep the pretrained encoder's weights as they are

    def __post_init__(self) -> None:
        if self.dim < 1 or self.layers < 0 or self.heads < 1 or self.dim % self.heads:
            raise ValueError(f"text encoder: dim ({self.dim}) must be a positive multiple of heads ({self.heads}), "
                             f"layers >= 0 (got {self.layers})")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"text encoder: dropout must lie in [0, 1), got {self.dropout}")


def text_config(options: TextConfig | dict[str, Any] | None) -> TextConfig:
    if isinstance(options, TextConfig):
        return options
    fields = {f.name: f for f in dataclasses.fields(TextConfig)}
    unknown = sorted(set(options or {}) - set(fields))
    if unknown:
        raise ValueError(f"the text encoder has no option {', '.join(unknown)} (options: {', '.join(fields)})")
    kinds = {name: type(value) for name, value in dataclasses.asdict(TextConfig()).items()}  # each option's type, by its default
    values = {k: _flag(v) if kinds[k] is bool else kinds[k](v) for k, v in (options or {}).items()}
    return TextConfig(**values)


def _flag(value: Any) -> bool:
    return value if isinstance(value, bool) else parse_flag(str(value))


class TextEncoder(nn.Module):
    """Token ids ``[B, L]`` -> one vector per instruction ``[B, dim]`` (module docstring)."""

    def __init__(self, vocab_size: int, max_tokens: int, config: TextConfig):
        super().__init__()
        self.embed = nn.Embedding(vocab_size, config.dim, padding_idx=0)
        self.position = nn.Parameter(torch.zeros(max_tokens, config.dim))
        nn.init.normal_(self.position, std=0.02)
        self.layers = nn.ModuleList(
            nn.TransformerEncoderLayer(config.dim, config.heads, 4 * config.dim, config.dropout, batch_first=True,
                                       norm_first=True) for _ in range(config.layers))
        self.norm = nn.LayerNorm(config.dim)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        x, pad = self.per_token(tokens)
        keep = (~pad).unsqueeze(-1).to(x.dtype)
        return self.norm((x * keep).sum(dim=1) / keep.sum(dim=1).clamp(min=1.0))

    def per_token(self, tokens: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Token ids ``[B, L]`` -> each token's output ``[B, L, dim]`` and the padding ``[B, L]`` (True: ignore it;
        a blanked instruction keeps its padding, which is then all it has to attend to)."""
        pad = tokens == 0
        x = self.embed(tokens) + self.position[: tokens.shape[1]]
        empty = pad.all(dim=1, keepdim=True)  # no token at all (a blanked instruction): attend to the padding
        pad = pad & ~empty
        for layer in self.layers:
            x = layer(x, src_key_padding_mask=pad)
        return x, pad


class InstructedPolicy(Policy):
    """A wrapped policy told the instruction's vector: by FiLM in its hidden layers where it takes a
    condition (``film``: BC's MLP, on state or behind cameras), else appended to every frame's low-dim
    observation, and with ``film_images`` by FiLM in its image encoders as well; a policy that reads tokens
    (``tokens``: the transformer) is given the encoder's per-word outputs instead."""

    def __init__(self, spec: PolicySpec, config: Any, text: TextConfig, build: Callable[[PolicySpec], Policy],
                 film: bool = False, film_images: bool = False, tokens: bool = False):
        super().__init__(spec, config)
        self.text_config = text
        self.film, self.film_images, self.tokens = film, film_images, tokens
        self.text = TextEncoder(spec.vocab, spec.max_tokens, text)
        inner: dict[str, Any] = (dict(text_dim=text.dim) if tokens else dict(cond_dim=text.dim) if film
                                 else dict(obs_dim=spec.obs_dim + text.dim))
        if film_images:  # the image encoders take it too (demo.policies.encoders.CameraEncoder)
            inner.update(cond_dim=text.dim, film_cameras=True, film_head=film)
        self.inner = build(dataclasses.replace(spec, vocab=0, max_tokens=0, **inner))
        self.name = self.inner.name

    def condition(self, obs: dict[str, torch.Tensor]) -> torch.Tensor | dict[str, torch.Tensor]:
        """The wrapped policy's observation: with FiLM, ``{state, condition}``; else its low-dim vector with
        the instruction's vector appended (and its cameras)."""
        state = obs[STATE]
        # A batch holds a few distinct instructions (one per task): each is encoded once, the same numbers
        # and gradients as encoding every row (4x faster training steps on MT10's ten).
        unique, row = torch.unique(obs[INSTRUCTION], dim=0, return_inverse=True)
        if self.tokens:  # the words as tokens, beside the observation (and its cameras)
            x, pad = self.text.per_token(unique)
            return {**{k: v for k, v in obs.items() if k != INSTRUCTION}, TEXT_TOKENS: x[row].to(state.dtype),
                    TEXT_PAD: pad[row]}
        words = self.text(unique)[row].to(state.dtype)
        if not self.film:
            state = torch.cat([state, words[:, None, :].expand(-1, state.shape[1], -1)], dim=-1)
        rest = {k: v for k, v in obs.items() if k not in (STATE, INSTRUCTION)}
        if self.film or self.film_images:
            rest[CONDITION] = words
        return {STATE: state, **rest} if rest else state

    def loss(self, obs: dict[str, torch.Tensor], action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        return self.inner.loss(self.condition(obs), action, action_pad)

    def fit_actions(self, low: np.ndarray, high: np.ndarray) -> None:
        self.inner.fit_actions(low, high)

    @torch.no_grad()
    def predict(self, obs: dict[str, torch.Tensor], generator: torch.Generator | None = None) -> torch.Tensor:
        return self.inner.predict(self.condition(obs), generator=generator)


def text_record(policy: Policy) -> dict[str, Any] | None:
    """The text-encoder settings run.json records for an instruction-conditioned policy (else None)."""
    return dataclasses.asdict(policy.text_config) if isinstance(policy, InstructedPolicy) else None


SHAPE_FIELDS = ("dim", "layers", "heads")  # what a pretrained encoder fixes of the text configuration


@dataclass
class PretrainedText:
    """A text encoder trained before, read from a run directory (:func:`pretrained_text`)."""

    tokenizer: InstructionTokenizer
    config: TextConfig  # its dim, layers and heads
    weights: dict[str, torch.Tensor]  # the TextEncoder's state dict


def pretrained_text(path: str) -> PretrainedText:
    """The tokenizer, text-encoder shape and weights of the instruction-conditioned run at ``path`` (read-only:
    run.json and policy.safetensors, never unpickled); a one-line error for anything else."""
    from demo.errors import DemoError
    from demo.policies import checkpoint as ckpt  # deferred: the checkpoint module imports this one

    bundle = ckpt.load_bundle(path)
    policy = bundle.policy
    if not isinstance(policy, InstructedPolicy) or bundle.tokenizer is None:
        raise DemoError(path, "is not an instruction-conditioned run: it has no text encoder to start from "
                              "(--text-opt init=RUN)")
    weights = {k: v.detach().clone() for k, v in policy.text.state_dict().items()}
    return PretrainedText(bundle.tokenizer, policy.text_config, weights)


def with_pretrained_shape(options: dict[str, Any], pretrained: PretrainedText) -> TextConfig:
    """The text configuration ``options`` (``--text-opt``) with the pretrained encoder's dim, layers and heads;
    a ValueError where ``options`` set one of them to something else."""
    text = text_config(options)
    differ = [f"{k}={options[k]} (the encoder has {getattr(pretrained.config, k)})" for k in SHAPE_FIELDS
              if k in options and int(options[k]) != getattr(pretrained.config, k)]
    if differ:
        raise ValueError(f"init={text.init} fixes the encoder's shape: {', '.join(differ)}")
    return dataclasses.replace(text, **{k: getattr(pretrained.config, k) for k in SHAPE_FIELDS})
