"""A transformer over tokens (RT-1's and the VLAs' layout at a size a CPU trains): ``demo train DATA --algo transformer``.

Reads top to bottom:

1. :class:`TransformerConfig`: the network's hyperparameters (``--policy-opt name=value``).
2. :class:`TransformerPolicy`: every input is a sequence of tokens of one width, ``d_model``:

   - *the low-dim state*: one token per history frame from the whole vector (a linear map), or with
     ``state_tokens=objects`` one per object (:func:`object_columns`: the arm's values one token, each cube's
     another), each group of objects its own map and each token its own learned embedding, so that attention
     can pick the object the words name;
   - *cameras*: one token per camera per frame from its encoder's features (a policy from cameras sits
     behind :class:`demo.policies.visuomotor.VisuomotorPolicy`, whose per-camera features arrive in the
     frame's vector; ``spec.token_dims`` says where each camera's part starts), each camera its own map;
   - *instruction*: one token per word, the text encoder's per-token outputs
     (:class:`demo.policies.instruction.TextEncoder`, trained with the policy end to end), padding masked;

   each with a learned embedding of its kind (which camera, proprioception, words) and of its frame. A
   transformer encoder mixes them; a transformer decoder's ``horizon`` learned queries attend to the result
   and become the chunk ``[H, A]`` (ACT's decoder without the CVAE: one chunk per observation).
3. :meth:`TransformerPolicy.loss`: the chunk's L1 error (ACT's; ``loss=mse`` for the squared error) on the steps
   before the episode end. From cameras, each sample's proprioception tokens are hidden from attention with
   probability ``state_dropout`` (ACT's remedy, :mod:`demo.policies.act`): with the joints always in view the
   transformer fits the demonstrations from them and never learns to read its cameras.

Execution is the shared executor's (:mod:`demo.policies.actor`): a query every step, temporally ensembled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from demo.policies.act import check_transformer, hide_state_draw, state_token_padding, token_sizes
from demo.policies.heads import masked_mean
from demo.policies.instruction import TEXT_PAD, TEXT_TOKENS
from demo.policies.observation import STATE
from demo.policies.policy import Policy, PolicySpec, register_policy


# ================================================================================== 1. config
LOSSES = ("mse", "l1")
STATE_TOKENS = ("frame", "objects")


@dataclass
class TransformerConfig:
    """The token transformer's hyperparameters (``--policy-opt name=value``)."""

    d_model: int = 128  # token width
    heads: int = 4
    layers: int = 3  # encoder layers over every token
    decoder_layers: int = 1  # decoder layers of the chunk queries (ACT's: 1)
    feedforward: int = 512
    dropout: float = 0.1
    # From cameras: in training, each sample's proprioception tokens are hidden from attention with this probability
    # (ignored without cameras). Why: from gym-aloha's transfer cube (top camera + joints, 400-step probes) the
    # transformer with its joints always in view never read the camera (images shuffled across a validation batch:
    # chunk L1 within 1%, 0.047); ACT, blind the same way, went from 7/100 to 100/100 with this remedy at 0.5.
    state_dropout: float = 0.5
    # The chunk's error: l1 (absolute, ACT's) | mse (squared). pick, 100 demonstrations, the defaults otherwise
    # (10,000 steps): 96/100 with L1 against 66/100 with the squared error (docs/results.md, "Told in words").
    loss: str = "l1"
    # How the low-dim state becomes tokens: frame (one token per frame) | objects (one per object, object_columns).
    # Why objects: on place (three cubes, three pads, the words name one of each) the one-token transformer closed
    # over the named cube no more often than chance.
    state_tokens: str = "frame"

    def __post_init__(self) -> None:
        check_transformer(self.d_model, self.heads, self.dropout, layers=self.layers,
                          decoder_layers=self.decoder_layers, feedforward=self.feedforward)
        if not 0.0 <= self.state_dropout < 1.0:
            raise ValueError(f"state_dropout must lie in [0, 1), got {self.state_dropout}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        if self.state_tokens not in STATE_TOKENS:
            raise ValueError(f"state_tokens must be one of {', '.join(STATE_TOKENS)}, got {self.state_tokens!r}")


def object_columns(layout: tuple[tuple[int, int], ...]) -> list[torch.Tensor]:
    """The low-dim vector's columns per object, grouped: ``[objects, values per object]`` (long) per group.

    ``layout`` is :attr:`PolicySpec.obs_layout` (per key: rows, values per row). Keys with the same number of rows
    describe the same objects row by row (place's cube positions (3, 3), orientations (3, 4) and pads (3, 3): row i
    of each is colour i's), so one group's token i holds row i of each; the keys of one row (the arm's joints, its
    end effector) are one token together."""
    starts = np.cumsum([0] + [rows * width for rows, width in layout])
    groups: dict[int, list[np.ndarray]] = {}
    for (rows, width), start in zip(layout, starts):
        groups.setdefault(rows, []).append(start + np.arange(rows * width).reshape(rows, width))
    return [torch.as_tensor(np.concatenate(parts, axis=1)) for _, parts in sorted(groups.items())]


# ================================================================================== 2. the network
@register_policy("transformer")
class TransformerPolicy(Policy):
    Config = TransformerConfig
    takes_tokens = True

    def __init__(self, spec: PolicySpec, config: TransformerConfig):
        super().__init__(spec, config)
        c, d = config, config.d_model
        self.sizes = token_sizes(spec)  # the low-dim state, then each camera's features
        # the state's tokens: per group of objects, its columns in the vector [objects, values per object]
        groups = object_columns(spec.obs_layout) if c.state_tokens == "objects" else [torch.arange(self.sizes[0])[None]]
        if c.state_tokens == "objects" and sum(g.numel() for g in groups) != self.sizes[0]:
            raise ValueError("state_tokens=objects needs the observation's layout by key (spec.obs_layout), which this "
                             "run does not record (trained before it): use state_tokens=frame")
        for k, columns in enumerate(groups):
            self.register_buffer(f"columns{k}", columns, persistent=False)
        self.n_state = sum(len(g) for g in groups)
        # one map per source of tokens: each group of objects (the whole vector: one), then each camera
        self.frame_in = nn.ModuleList([nn.Linear(g.shape[1], d) for g in groups] +
                                      [nn.Linear(n, d) for n in self.sizes[1:]])
        self.n_groups = len(groups)
        # each frame token's kind (every state row, then each camera); the last: words
        self.kind = nn.Parameter(torch.zeros(self.n_state + len(self.sizes), d))
        self.frame = nn.Parameter(torch.zeros(spec.n_obs, 1, d))
        self.text_in = nn.Linear(spec.text_dim, d) if spec.text_dim else None
        layer = nn.TransformerEncoderLayer(d, c.heads, c.feedforward, c.dropout, batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, c.layers, norm=nn.LayerNorm(d), enable_nested_tensor=False)
        self.queries = nn.Parameter(torch.zeros(1, spec.horizon, d))
        layer = nn.TransformerDecoderLayer(d, c.heads, c.feedforward, c.dropout, batch_first=True, norm_first=True)
        self.decoder = nn.TransformerDecoder(layer, c.decoder_layers, norm=nn.LayerNorm(d))
        self.action_out = nn.Linear(d, spec.action_dim)
        for p in (self.kind, self.frame, self.queries):
            nn.init.normal_(p, std=0.02)

    def tokens(self, obs: torch.Tensor | dict[str, torch.Tensor],
               hide_state: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Every input token ``[B, T, d_model]`` and the padding mask ``[B, T]`` (True: hidden; None when nothing
        is); ``hide_state [B]`` (bool) hides those samples' proprioception tokens (training's ``state_dropout``)."""
        state = obs[STATE] if isinstance(obs, dict) else obs  # [B, n_obs, obs_dim]
        low_dim, *cameras = torch.split(state, self.sizes, dim=-1)
        objects = [self.frame_in[k](low_dim[..., getattr(self, f"columns{k}")]) for k in range(self.n_groups)]
        cameras = [embed(part)[:, :, None] for embed, part in zip(self.frame_in[self.n_groups:], cameras)]
        frames = torch.cat(objects + cameras, dim=2) + self.kind[:-1] + self.frame  # [B, n_obs, tokens per frame, d]
        x = frames.flatten(1, 2)
        pad = None if hide_state is None else state_token_padding(hide_state, state.shape[1], frames.shape[2],
                                                                  self.n_state)
        if self.text_in is None:
            return x, pad
        words = self.text_in(obs[TEXT_TOKENS].to(x.dtype)) + self.kind[-1]  # type: ignore[index]
        if pad is None:
            pad = torch.zeros(x.shape[:2], dtype=torch.bool, device=x.device)
        return torch.cat([x, words], dim=1), torch.cat([pad, obs[TEXT_PAD]], dim=1)  # type: ignore[index]

    def forward(self, obs: torch.Tensor | dict[str, torch.Tensor], hide_state: torch.Tensor | None = None) -> torch.Tensor:
        """The normalised chunk ``[B, H, A]``."""
        x, pad = self.tokens(obs, hide_state)
        memory = self.encoder(x, src_key_padding_mask=pad)
        queries = self.queries.expand(x.shape[0], -1, -1)
        return self.action_out(self.decoder(queries, memory, memory_key_padding_mask=pad))

    # ============================================================================== 3. loss
    def loss(self, obs: torch.Tensor | dict[str, torch.Tensor], action: torch.Tensor,
             action_pad: torch.Tensor) -> torch.Tensor:
        hide_state = hide_state_draw(self.training, action.shape[0], self.config.state_dropout, len(self.sizes),
                                     action.device)
        error = self(obs, hide_state) - action
        return masked_mean(error.abs() if self.config.loss == "l1" else error.square(), ~action_pad)

    @torch.no_grad()
    def predict(self, obs: torch.Tensor | dict[str, torch.Tensor], generator: torch.Generator | None = None) -> torch.Tensor:
        return self(obs)
