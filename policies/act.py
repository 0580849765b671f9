"""ACT, the Action Chunking Transformer (Zhao et al. 2023): ``demo train DATA --algo act``.

Reads top to bottom:

1. :class:`ACTConfig`: the network's hyperparameters. ACT's published sizes (d_model 512, 4 + 7
   layers, feed-forward 3200, chunk 100 at 50 Hz) are sized for a GPU; the defaults here are a
   CPU-sized transformer of the same layout. The training-loop settings (chunk, learning rate,
   execution with temporal ensembling) are in :data:`demo.training.config.POLICY_DEFAULTS`.
2. :class:`ACTPolicy`, a conditional VAE whose decoder is a transformer:

   - *CVAE encoder* (training only): a transformer encoder over ``[CLS, observation, a_0 .. a_{H-1}]``
     (the current frame's normalised observation and the demonstrated chunk, one token each, with
     learned position embeddings; padded chunk steps are masked out of the attention, as ACT's
     ``is_pad``) gives ``mu, logvar`` of the style variable ``z`` from the CLS token;
   - *decoder*: a transformer encoder over ``[z, o_1 .. o_{n_obs}]`` (one token per observation
     frame; a visuomotor policy's frames carry the cameras' features, :mod:`demo.policies.visuomotor`,
     and each frame becomes one token for the proprioception and one per camera, as ACT keeps its joints
     and its images apart), then a transformer decoder whose ``horizon`` learned queries attend to that
     memory and become the chunk ``[H, A]``. The CVAE encoder reads the proprioception only (ACT's).

3. :meth:`ACTPolicy.loss`: L1 between the predicted and the demonstrated chunk on the steps before
   the episode end, plus ``kl_weight`` times the KL divergence of ``N(mu, sigma)`` from ``N(0, I)``
   (summed over the latent dimensions, mean over the batch: ACT's ``kl_divergence``; published
   weight 10, here 0.01: see :class:`ACTConfig`). From cameras, each sample's proprioception tokens are
   hidden from the decoder with probability ``state_dropout``: with the joints always in view the
   transformer fits the demonstrations from them alone and never learns to read the camera (see
   :class:`ACTConfig`).
4. :meth:`ACTPolicy.predict`: by default (``latent=commit``) ``z`` drawn from the prior once per
   episode (the rollout generator's next numbers, read without consuming them), so that where ``z``
   carries a mode the whole episode keeps it; ``latent=zero`` is the paper's ``z = 0``, a
   deterministic query; ``latent=sample`` draws a new ``z`` at every query.

Execution is the shared executor (:mod:`demo.policies.actor`): a query every step and temporal
ensembling of every chunk covering the step, weights ``exp(-m i)`` with ``i = 0`` the oldest (ACT's
``exp(-k i)``, ``k = 0.01`` = ``--ensemble-decay``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from demo.policies.heads import masked_mean, peek
from demo.policies.policy import Policy, PolicySpec, register_policy

LATENTS = ("zero", "sample", "commit")


# ================================================================================== 1. config
@dataclass
class ACTConfig:
    """ACT's hyperparameters (``--policy-opt name=value``)."""

    d_model: int = 128  # token width (published: 512)
    heads: int = 4  # attention heads (published: 8)
    encoder_layers: int = 2  # decoder side's transformer encoder over [z, observation frames] (published: 4)
    # transformer decoder of the chunk queries (published: 7, of which the original code uses the
    # first layer's output only; LeRobot's ACT sets 1 to match)
    decoder_layers: int = 1
    vae_layers: int = 2  # CVAE encoder over [CLS, observation, actions] (published: 4)
    feedforward: int = 512  # feed-forward width in every layer (published: 3200)
    dropout: float = 0.1  # published: 0.1
    latent_dim: int = 32  # style variable z (published: 32)
    # beta of the KL term (published: 10). At 10 the latent carries nothing: one bit of "which side" costs
    # ~7 loss units against an L1 gain of a few hundredths, and on avoid (bimodal, 200 demos) ACT
    # averages the sides into the obstacle: 49/100 (z = 0), 51/100 (z sampled). At 0.01: 84/100 (z = 0),
    # 85/100 (commit), 76/100 (z sampled per query: ensembled chunks of different z average the modes).
    kl_weight: float = 0.01
    # From cameras: in training, each sample's proprioception tokens are hidden from the decoder's attention with
    # this probability (ignored without cameras). Why: on gym-aloha's transfer cube (50 demos, top camera + joints)
    # ACT with its joints always in view fitted the chunks from them alone: shuffling the images across a batch
    # changed its predicted chunks by 0.001 (diffusion's: 0.04), its camera features had collapsed (spread 0.006
    # against diffusion's 0.23), and it scored 7/100 where diffusion scored 99. The start state holds the cube's
    # place only in the image. Hiding the joints (0.2 or 0.5) made the camera matter within 200 steps; at 0.5 and
    # the defaults otherwise, transfer cube 100/100 (docs/environments.md).
    state_dropout: float = 0.5
    # z at inference: zero (the prior's mean, published) | sample (from the prior, seeded, per query) |
    # commit (one draw from the prior per episode: every query of a rollout uses the same z)
    latent: str = "commit"

    def __post_init__(self) -> None:
        check_transformer(self.d_model, self.heads, self.dropout, encoder_layers=self.encoder_layers,
                          decoder_layers=self.decoder_layers, vae_layers=self.vae_layers, feedforward=self.feedforward,
                          latent_dim=self.latent_dim)
        if not 0.0 <= self.state_dropout < 1.0:
            raise ValueError(f"state_dropout must lie in [0, 1), got {self.state_dropout}")
        if self.kl_weight < 0:
            raise ValueError(f"kl_weight must be >= 0, got {self.kl_weight}")
        if self.latent not in LATENTS:
            raise ValueError(f"latent must be one of {', '.join(LATENTS)}, got {self.latent!r}")


def check_transformer(d_model: int, heads: int, dropout: float, **sizes: int) -> None:
    """A ValueError for a transformer's sizes that cannot build: every size and ``heads`` positive, ``d_model`` a
    multiple of ``heads``, ``dropout`` in [0, 1)."""
    small = [name for name, value in {"d_model": d_model, "heads": heads, **sizes}.items() if value < 1]
    if small:
        raise ValueError(f"{', '.join(small)} must be positive")
    if d_model % heads:
        raise ValueError(f"d_model ({d_model}) must be divisible by heads ({heads})")
    if not 0.0 <= dropout < 1.0:
        raise ValueError(f"dropout must lie in [0, 1), got {dropout}")


def token_sizes(spec: PolicySpec) -> list[int]:
    """Widths of one frame's tokens in the observation vector: the proprioception, then each camera's features
    (``spec.token_dims``, set by :class:`demo.policies.visuomotor.VisuomotorPolicy`), or the whole vector as one."""
    sizes = list(spec.token_dims or (spec.obs_dim,))
    if sum(sizes) != spec.obs_dim:
        raise ValueError(f"token sizes {sizes} do not add up to the observation's {spec.obs_dim} entries")
    return sizes


def hide_state_draw(training: bool, batch: int, p: float, tokens_per_frame: int, device: torch.device) -> torch.Tensor | None:
    """Training's ``state_dropout`` draw: ``[batch]`` bool, True for the samples whose proprioception tokens are
    hidden this step (probability ``p``); None in evaluation, without cameras (one token per frame), or at ``p = 0``."""
    if not (training and tokens_per_frame > 1 and p > 0):
        return None
    return torch.rand(batch, device=device) < p


def state_token_padding(hide_state: torch.Tensor, frames: int, tokens_per_frame: int, state_tokens: int = 1) -> torch.Tensor:
    """The key padding mask ``[B, frames * tokens_per_frame]`` (True: hidden) of frame tokens laid out frame by frame,
    the proprioception's ``state_tokens`` first in each frame: each hidden sample's proprioception tokens, nothing else."""
    state_token = torch.zeros(tokens_per_frame, dtype=torch.bool, device=hide_state.device)
    state_token[:state_tokens] = True
    return (hide_state[:, None, None] & state_token).expand(-1, frames, -1).flatten(1)


def _encoder(c: ACTConfig, layers: int) -> nn.TransformerEncoder:
    # Pre-norm: trains without ACT's 1e-5 learning rate at the loop's warm-up + cosine schedule.
    layer = nn.TransformerEncoderLayer(c.d_model, c.heads, c.feedforward, c.dropout, batch_first=True, norm_first=True)
    return nn.TransformerEncoder(layer, layers, norm=nn.LayerNorm(c.d_model), enable_nested_tensor=False)


# ================================================================================== 2. the network
@register_policy("act")
class ACTPolicy(Policy):
    Config = ACTConfig

    def __init__(self, spec: PolicySpec, config: ACTConfig):
        super().__init__(spec, config)
        c, d = config, config.d_model
        # each frame's vector: the proprioception, then each camera's features (one token each)
        self.sizes = token_sizes(spec)
        state_dim = self.sizes[0]
        # CVAE encoder: [CLS, proprioception (current frame), actions]
        self.cls = nn.Parameter(torch.zeros(1, 1, d))
        self.vae_obs = nn.Linear(state_dim, d)
        self.vae_action = nn.Linear(spec.action_dim, d)
        self.vae_pos = nn.Parameter(torch.zeros(1, 2 + spec.horizon, d))
        self.vae = _encoder(c, c.vae_layers)
        self.latent_proj = nn.Linear(d, 2 * c.latent_dim)  # -> mu, logvar
        # decoder: memory [z, each frame's proprioception and camera tokens], then chunk queries
        self.latent_in = nn.Linear(c.latent_dim, d)
        self.obs_in = nn.Linear(state_dim, d)
        self.camera_in = nn.ModuleList(nn.Linear(n, d) for n in self.sizes[1:])
        self.memory_pos = nn.Parameter(torch.zeros(1, 1 + spec.n_obs * len(self.sizes), d))
        self.encoder = _encoder(c, c.encoder_layers)
        self.queries = nn.Parameter(torch.zeros(1, spec.horizon, d))
        layer = nn.TransformerDecoderLayer(d, c.heads, c.feedforward, c.dropout, batch_first=True, norm_first=True)
        self.decoder = nn.TransformerDecoder(layer, c.decoder_layers, norm=nn.LayerNorm(d))
        self.action_out = nn.Linear(d, spec.action_dim)
        for p in (self.cls, self.vae_pos, self.memory_pos, self.queries):
            nn.init.normal_(p, std=0.02)
        # The posterior starts as the prior (KL 0): random mu/logvar would start the KL term at
        # 20-60 (x kl_weight 10), and the first few hundred steps would go to shrinking it.
        nn.init.zeros_(self.latent_proj.weight)
        nn.init.zeros_(self.latent_proj.bias)

    def posterior(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``mu, logvar [B, latent_dim]`` of z given the current frame and the demonstrated chunk."""
        b = action.shape[0]
        state = obs[:, -1:, : self.sizes[0]]
        tokens = torch.cat([self.cls.expand(b, -1, -1), self.vae_obs(state), self.vae_action(action)], dim=1)
        # CLS and observation are never padded; padded chunk steps are invisible to attention
        pad = torch.cat([torch.zeros(b, 2, dtype=torch.bool, device=action.device), action_pad], dim=1)
        cls = self.vae(tokens + self.vae_pos, src_key_padding_mask=pad)[:, 0]
        mu, logvar = self.latent_proj(cls).chunk(2, dim=-1)
        return mu, logvar

    def decode(self, obs: torch.Tensor, z: torch.Tensor, hide_state: torch.Tensor | None = None) -> torch.Tensor:
        """The chunk ``[B, H, A]`` for ``obs [B, n_obs, D]`` and style ``z [B, latent_dim]``; ``hide_state [B]``
        (bool) hides those samples' proprioception tokens from attention (training's ``state_dropout``)."""
        b, frames = obs.shape[:2]
        parts = torch.split(obs, self.sizes, dim=-1)
        per_frame = torch.stack([self.obs_in(parts[0]), *(embed(part) for embed, part in zip(self.camera_in, parts[1:]))],
                                dim=2)  # [B, n_obs, tokens per frame, d]
        memory = torch.cat([self.latent_in(z).unsqueeze(1), per_frame.flatten(1, 2)], dim=1) + self.memory_pos
        pad = None
        if hide_state is not None:
            pad = torch.cat([torch.zeros(b, 1, dtype=torch.bool, device=obs.device),
                             state_token_padding(hide_state, frames, len(self.sizes))], dim=1)
        memory = self.encoder(memory, src_key_padding_mask=pad)
        return self.action_out(self.decoder(self.queries.expand(b, -1, -1), memory, memory_key_padding_mask=pad))

    # ---------------------------------------------------------------- 3. training: L1 + beta KL
    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        mu, logvar = self.posterior(obs, action, action_pad)
        z = mu + (0.5 * logvar).exp() * torch.randn_like(mu)  # reparameterisation
        hide_state = hide_state_draw(self.training, obs.shape[0], self.config.state_dropout, len(self.sizes), obs.device)
        l1 = masked_mean((self.decode(obs, z, hide_state) - action).abs(), ~action_pad)
        kl = (-0.5 * (1 + logvar - mu.square() - logvar.exp())).sum(dim=-1).mean()
        return l1 + self.config.kl_weight * kl

    # ---------------------------------------------------------------- 4. inference: z = 0
    @torch.no_grad()
    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        shape = (obs.shape[0], self.config.latent_dim)
        if self.config.latent == "sample":
            z = torch.randn(shape, generator=generator, device=obs.device, dtype=obs.dtype)
        elif self.config.latent == "commit":
            z = peek(generator, lambda: torch.randn(shape, generator=generator, device=obs.device, dtype=obs.dtype))
        else:
            z = torch.zeros(shape, device=obs.device, dtype=obs.dtype)
        return self.decode(obs, z)
