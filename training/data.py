"""Training data: store -> split -> normalisers -> windows, shared by every algorithm.

:func:`prepare` reads top to bottom:

1. **observations**: the store's low-dim ``obs.*`` keys are concatenated per frame (:class:`ObsSpec`);
2. **split**: episodes into training and validation (a store mask ``val_mask``, or a seeded random
   ``val_fraction`` of the episodes); failed episodes are left out unless ``include_failures``;
3. **normalisers**: min-max to [-1, 1] for observations and actions, fitted on the training frames
   (actions over every step of every training window, relative to the query frame when actions
   are relative, :mod:`demo.policies.relative`) and stored with the policy;
4. **windows**: :class:`Windows` over the normalised arrays gives observation histories
   ``[B, n_obs, D]`` and action chunks ``[B, chunk, A]``, padded at episode edges
   (:class:`demo.store.WindowSampler`). With cameras, an observation is a dict: the vector under
   ``"state"`` and each camera's uint8 images ``[B, n_obs, H, W, 3]`` under its key; images stay
   bytes in memory and become floats in the policy's encoder (:mod:`demo.policies.visuomotor`). With
   ``--aux-target KEYS`` the windows carry the query frame's state of those keys as well, min-max
   normalised like the observations, for the encoders' auxiliary loss.

Frames may carry a per-frame expert-label flag (:data:`LABEL_KEY`, written by DAgger): windows then
start at labelled frames only, and chunk steps on unlabelled frames count as padding (no loss). A
frame may also carry a chunk label (:data:`CHUNK_KEY`, DAgger's labels for a chunked learner: the
actions the expert would execute from that state on, looked ahead in the simulator; flagged by
:data:`HAS_CHUNK_KEY`): a window queried there takes it as its action chunk instead of the actions the
episode went on to execute.

:func:`prepare_union` trains on several stores as one (e.g. the same task on two arms, both in
``ee7``): frames concatenated store after store (episode ends offset), each store split with the
seed on its own, the normalisers fitted on the union's training frames. The stores must share the
task, the rate, the action representation and the chosen observations' shapes (:func:`check_union`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
import torch

from demo.errors import DemoError
from demo.store import EpisodeStore, WindowSampler
from demo.store.instructions import episode_instructions
from demo.store.layout import IMAGE_PREFIX
from demo.training.config import TrainConfig
from demo.policies.instruction import INSTRUCTION, InstructionTokenizer, PretrainedText, pretrained_text, text_config
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import STATE, ObsSpec
from demo.policies.policy import PolicySpec
from demo.policies.visuomotor import AUX_TARGET
from demo.policies.relative import RelativeActions, default_relative

LABEL_KEY = "info.labelled"  # optional per-frame flag: this frame's action is an expert label
CHUNK_KEY = "info.label_chunk"  # optional per-frame [H, A]: the expert's chunk from this state, where ...
HAS_CHUNK_KEY = "info.has_label_chunk"  # ... this per-frame flag is 1 (zeros elsewhere)
VALIDATION_WINDOWS = 4096  # windows of the fixed validation batch
VALIDATION_WINDOWS_IMAGES = 512  # with cameras: a validation pass stays a few seconds of encoder time
MIN_TRAIN_EPISODES = 2  # below this a policy sees one trajectory: refused, not trained silently

_UNIT = MinMaxNormalizer.from_limits(np.full(1, -1.0, np.float32), np.ones(1, np.float32))  # placeholder until fitted
# [B, n_obs, D], or {"state": that, camera key: uint8 [B, n_obs, H, W, 3], "instruction": int64 [B, max_tokens]}
Observation = torch.Tensor | dict[str, torch.Tensor]
Batch = tuple[Observation, torch.Tensor, torch.Tensor]  # obs, action [B, H, A], action_pad [B, H]
# Observations every arm reports in the same frame and units (scene frame, m, closedness): a union of
# arms with different joints trains on these (with the object's offset from the EE, see ObsSpec).
ROBOT_AGNOSTIC_KEYS = ("obs.ee_pos", "obs.ee_quat", "obs.gripper", "obs.object_pos", "obs.object_quat",
                       "obs.object_pos-obs.ee_pos")


@dataclass(frozen=True)
class Source:
    """One store of the training data: its episodes are ``first_episode ..`` in the concatenation."""

    path: str
    first_episode: int
    episodes: int


def batch_slice(batch: Batch, start: int, stop: int) -> Batch:
    """Windows ``start:stop`` of a batch."""
    obs, action, pad = batch
    part = {k: v[start:stop] for k, v in obs.items()} if isinstance(obs, dict) else obs[start:stop]
    return part, action[start:stop], pad[start:stop]


def images_shuffled(batch: Batch, seed: int) -> Batch | None:
    """The batch with every camera's images permuted across its windows (one permutation for all cameras, drawn
    from ``seed``), the rest unchanged; None for a batch without images. A policy's validation loss on it against
    the loss on ``batch`` says whether the policy reads its cameras at all: a policy that fits the demonstrations
    from the joints alone scores the same on both (ACT on gym-aloha's transfer cube did, and failed closed-loop)."""
    obs, action, pad = batch
    if not isinstance(obs, dict) or not any(k.startswith(IMAGE_PREFIX) for k in obs):
        return None
    order = torch.randperm(len(action), generator=torch.Generator().manual_seed(seed))
    return {k: v[order] if k.startswith(IMAGE_PREFIX) else v for k, v in obs.items()}, action, pad


def batch_to(batch: Batch, device: torch.device) -> Batch:
    """The batch on ``device`` (a no-op on the CPU)."""
    if device.type == "cpu":
        return batch
    obs, action, pad = batch
    moved = {k: v.to(device, non_blocking=True) for k, v in obs.items()} if isinstance(obs, dict) else obs.to(device, non_blocking=True)
    return moved, action.to(device, non_blocking=True), pad.to(device, non_blocking=True)


@dataclass(frozen=True)
class Instructions:
    """Every frame's instruction as token ids: ``tokens[of_frame[i]]`` is frame ``i``'s ``[max_tokens]``."""

    tokenizer: InstructionTokenizer  # trained on the training episodes' instructions (or the pretrained encoder's)
    texts: tuple[str, ...]  # the distinct instructions ("" for an episode without one)
    tokens: np.ndarray  # [len(texts), max_tokens] int64
    of_frame: np.ndarray  # [N] index into texts
    pretrained: PretrainedText | None = None  # --text-opt init=RUN: the encoder that starts the policy's, read once

    @classmethod
    def of(cls, tokenizer: InstructionTokenizer, per_episode: Sequence[str], ends: np.ndarray,
           pretrained: PretrainedText | None = None) -> "Instructions":
        texts = tuple(sorted(set(per_episode)))
        index = {text: k for k, text in enumerate(texts)}
        lengths = np.diff(np.concatenate([[0], ends]))
        of_frame = np.repeat(np.array([index[t] for t in per_episode], np.int64), lengths)
        return cls(tokenizer, texts, tokenizer.encode(texts), of_frame, pretrained)


@dataclass
class TrainingData:
    """A store's frames in memory with their split, normalisers and the shapes of the policy.

    Observations are normalised; actions stay raw, since their normalised form depends on the
    window's query frame when they are relative.
    """

    obs: np.ndarray  # [N, D] normalised observations (clipped to +-OBS_CLIP, as the actor does)
    action: np.ndarray  # [N, A] raw actions (the store's representation and units)
    base: np.ndarray | None  # [N, A] subtracted from the actions of windows queried at each frame; None = absolute
    ends: np.ndarray  # cumulative episode ends (every store episode)
    labelled: np.ndarray | None  # [N] bool, frames holding an expert label; None = every frame
    train_episodes: np.ndarray
    val_episodes: np.ndarray
    obs_spec: ObsSpec
    obs_norm: MinMaxNormalizer
    action_norm: MinMaxNormalizer
    relative: RelativeActions | None
    spec: PolicySpec  # obs_dim, action_dim, n_obs, horizon (= chunk), cameras
    images: dict[str, np.ndarray] = field(default_factory=dict)  # camera key -> [N, H, W, 3] uint8; none = state only
    sources: tuple[Source, ...] = ()  # the stores, in concatenation order (one unless a union)
    chunks: np.ndarray | None = None  # [N, H, A] raw chunk labels (CHUNK_KEY), all NaN on a frame without one
    instructions: Instructions | None = None  # the episodes' instructions, for an instruction-conditioned policy
    mix: tuple[float, ...] = ()  # per source, its share of each training batch (TrainConfig.mix); () = by windows
    aux: np.ndarray | None = None  # [N, aux_dim] normalised auxiliary targets (TrainConfig.aux_target); None = none
    aux_keys: tuple[str, ...] = ()  # the store keys they concatenate, in order
    aux_norm: MinMaxNormalizer | None = None  # fitted on the training frames

    def frames(self, episodes: np.ndarray) -> int:
        """Frames of ``episodes`` that hold an action label (all of them without label flags)."""
        starts = np.concatenate([[0], self.ends[:-1]])
        if self.labelled is None:
            return int((self.ends[episodes] - starts[episodes]).sum())
        return int(sum(self.labelled[starts[i] : self.ends[i]].sum() for i in episodes))

    def windows(self, episodes: np.ndarray) -> "Windows":
        return Windows(self, episodes)

    def validation_batch(self, seed: int) -> Batch | None:
        """The fixed validation windows (up to :data:`VALIDATION_WINDOWS`), or None without any."""
        return self.windows(self.val_episodes).fixed(VALIDATION_WINDOWS_IMAGES if self.images else VALIDATION_WINDOWS, seed)

    def validation_batches_by_instruction(self, seed: int) -> dict[str, Batch]:
        """Per instruction (task) of an instruction-conditioned run, the fixed validation windows of its validation
        episodes (those with none have no entry); {} for a run without instructions."""
        if self.instructions is None or not len(self.val_episodes):
            return {}
        starts = np.concatenate([[0], self.ends[:-1]])
        told = self.instructions.of_frame[starts[self.val_episodes]]  # each validation episode's instruction
        out = {}
        for k, text in enumerate(self.instructions.texts):
            episodes = self.val_episodes[told == k]
            batch = self.windows(episodes).fixed(VALIDATION_WINDOWS_IMAGES if self.images else VALIDATION_WINDOWS, seed) \
                if len(episodes) else None
            if batch is not None:
                out[text] = batch
        return out

    def reload(self, store: EpisodeStore, train_episodes: np.ndarray, val_episodes: np.ndarray) -> "TrainingData":
        """The store's frames now (it may have grown) with another split and *these* normalisers."""
        raw = _load_arrays(store, self.obs_spec, self.relative, self.aux_keys)
        instructions = None
        if self.instructions is not None:  # the same vocabulary: new words are unknown to it
            instructions = Instructions.of(self.instructions.tokenizer, episode_instructions([store]), raw.ends,
                                           self.instructions.pretrained)
        aux = None if self.aux_norm is None else _normalized_obs(raw.aux, self.aux_norm)
        return replace(self, obs=_normalized_obs(raw.obs, self.obs_norm), images=raw.images, action=raw.action, base=raw.base,
                       ends=raw.ends, labelled=raw.labelled, train_episodes=train_episodes, val_episodes=val_episodes,
                       sources=(Source(str(store.path), 0, len(raw.ends)),), chunks=raw.chunks, instructions=instructions,
                       aux=aux)


def prepare(config: TrainConfig, store: EpisodeStore, among: np.ndarray | None = None,
            split: tuple[np.ndarray, np.ndarray] | None = None) -> TrainingData:
    """Steps 1-3 for a resolved ``config``: split drawn from ``among`` (default: all episodes) or given.

    Refuses (DemoError) a training split below the minimum: :data:`MIN_TRAIN_EPISODES` episodes and
    one window's worth of labelled frames, ``n_obs + chunk - 1``.
    """
    obs_spec = ObsSpec.from_features(store.meta.features, config.obs_keys or None, str(store.path))
    relative = default_relative(store.meta) if config.relative_actions else None
    split = split if split is not None else split_episodes(store, config, among)
    return _assemble(config, [store], [split], obs_spec, relative)


def prepare_union(config: TrainConfig, stores: Sequence[EpisodeStore]) -> TrainingData:
    """Steps 1-3 on several stores as one (one store: :func:`prepare`): frames concatenated store after
    store, each store's episodes split with the seed on its own (``val_fraction`` or ``val_mask`` of
    each), normalisers fitted on the union's training frames. Refuses stores that cannot share a
    policy (:func:`check_union`), naming the store at fault."""
    if len(stores) == 1:
        return prepare(config, stores[0])
    paths = [s.path.resolve() for s in stores]
    twice = next((s.path for s, p in zip(stores, paths) if paths.count(p) > 1), None)
    if twice is not None:
        raise DemoError(twice, "is named twice; a union takes each store once")
    first = stores[0]
    obs_spec = ObsSpec.from_features(first.meta.features, config.obs_keys or None, str(first.path))
    # Told what to do in words, one policy learns several tasks: the stores may hold different ones.
    instructed = config.instructions is not False and all(_every_episode_told(s) for s in stores)
    for store in stores[1:]:
        check_union(first, store, obs_spec, same_task=not instructed)
    relative = default_relative(first.meta) if config.relative_actions else None
    return _assemble(config, stores, [split_episodes(store, config) for store in stores], obs_spec, relative)


@contextlib.contextmanager
def open_stores(paths: Sequence[str]) -> Iterator[list[EpisodeStore]]:
    """The stores at ``paths``, open for reading until the block ends."""
    with contextlib.ExitStack() as stack:
        yield [stack.enter_context(EpisodeStore.open(p)) for p in paths]


def _every_episode_told(store: EpisodeStore) -> bool:
    texts = episode_instructions([store])
    return bool(texts) and all(texts)


def check_union(first: EpisodeStore, store: EpisodeStore, obs_spec: ObsSpec, same_task: bool = True) -> None:
    """Refuse (one DemoError naming ``store``) a store that cannot share a policy with ``first``:
    another task (unless ``same_task`` is False: every episode carries an instruction) or rate, another
    action representation (joint-space actions of arms with other joints included), or observations
    ``obs_spec`` reads that it lacks or holds in another shape."""
    a, b, where = first.meta, store.meta, store.path
    convert = "convert every store with `demo convert STORE --to ee7 --out ...`"
    task_a, task_b = a.task or {}, b.task or {}
    if same_task and (task_a.get("name"), task_a.get("options")) != (task_b.get("name"), task_b.get("options")):
        raise DemoError(where, f"holds task {task_b.get('name')!r} {task_b.get('options') or ''}, {first.path} "
                               f"{task_a.get('name')!r} {task_a.get('options') or ''}: one policy trains on one task "
                               "unless every episode carries an instruction (demo collect --instruction)")
    if a.fps != b.fps:
        raise DemoError(where, f"runs at {b.fps} Hz, {first.path} at {a.fps} Hz: one policy acts at one rate")
    if a.action.to_json() != b.action.to_json():
        if a.action.frame == "joint" and b.action.frame == "joint":
            mine, theirs = (list(x.action.params.get("arm_joints") or x.action.names) for x in (b, a))
            raise DemoError(where, f"{b.action.name} actions of {len(mine)} joints ({', '.join(mine)}) cannot share a "
                                   f"policy with {first.path}'s {len(theirs)} joints ({', '.join(theirs)}): joint-space "
                                   f"actions of arms with different joints cannot share a policy; {convert}")
        raise DemoError(where, f"holds {b.action.name} actions ({b.action.dim} values), {first.path} {a.action.name} "
                               f"({a.action.dim}): one policy outputs one action representation; {convert}")
    hint = f"choose observations every robot reports, e.g. --obs-keys {','.join(ROBOT_AGNOSTIC_KEYS)}"
    try:
        theirs = ObsSpec.from_features(b.features, list(obs_spec.keys) + list(obs_spec.images), str(where))
    except DemoError as exc:
        raise DemoError(where, f"{exc.problem}; {hint}") from None
    pairs = zip((*obs_spec.keys, *obs_spec.images), (*obs_spec.dims, *obs_spec.image_shapes), (*theirs.dims, *theirs.image_shapes))
    for key, mine, other in pairs:
        if mine != other:
            source = key.partition("-")[0]  # a difference "obs.a-obs.b" has obs.a's shape
            raise DemoError(where, f"observation {source} is {tuple(b.features[source].shape)} here and "
                                   f"{tuple(a.features[source].shape)} in {first.path}; {hint}")


def _assemble(config: TrainConfig, stores: Sequence[EpisodeStore], splits: Sequence[tuple[np.ndarray, np.ndarray]],
              obs_spec: ObsSpec, relative: RelativeActions | None) -> TrainingData:
    """The stores' frames one after another with their splits (episode indices offset), the
    minimum checked, normalisers fitted on the training frames of all of them."""
    targets = aux_keys(config.aux_target, stores, obs_spec) if config.aux_target else ()
    parts = [_load_arrays(store, obs_spec, relative, targets) for store in stores]
    first_episode = np.cumsum([0] + [len(p.ends) for p in parts])
    first_frame = np.cumsum([0] + [int(p.ends[-1]) if len(p.ends) else 0 for p in parts])
    obs, action = _join([p.obs for p in parts]), _join([p.action for p in parts])
    base = None if relative is None else _join([p.base for p in parts])
    ends = _join([p.ends + first_frame[i] for i, p in enumerate(parts)])
    labelled = None
    if any(p.labelled is not None for p in parts):  # a store without label flags is labelled throughout
        labelled = _join([p.labelled if p.labelled is not None else np.ones(len(p.action), bool) for p in parts])
    images = {k: _join([p.images[k] for p in parts]) for k in obs_spec.images}
    chunks = None
    if any(p.chunks is not None for p in parts):  # a store without chunk labels has none on any frame
        horizon = max(p.chunks.shape[1] for p in parts if p.chunks is not None)
        chunks = _join([_chunk_rows(p.chunks, len(p.action), horizon, p.action.shape[1]) for p in parts])
    train_eps = _join([s[0] + first_episode[i] for i, s in enumerate(splits)])
    val_eps = _join([s[1] + first_episode[i] for i, s in enumerate(splits)])
    sources = tuple(Source(str(s.path), int(first_episode[i]), len(p.ends)) for i, (s, p) in enumerate(zip(stores, parts)))
    frames = frame_indices(ends, train_eps)
    if labelled is not None:
        frames = frames[labelled[frames]]
    window = config.n_obs + config.chunk - 1
    if len(train_eps) < MIN_TRAIN_EPISODES or len(frames) < window:
        where = ", ".join(str(s.path) for s in stores)
        raise DemoError(where, f"too little to train on: {len(train_eps)} training episode(s) with {len(frames)} "
                               f"labelled frame(s); the minimum is {MIN_TRAIN_EPISODES} episodes and one window "
                               f"of {window} frames (n_obs {config.n_obs} + chunk {config.chunk} - 1)")
    obs_norm = MinMaxNormalizer.fit(obs[frames])
    cameras = tuple((key, shape[0], shape[1]) for key, shape in zip(obs_spec.images, obs_spec.image_shapes))
    spec = PolicySpec(obs_spec.dim, stores[0].meta.action.dim, config.n_obs, config.chunk, cameras,
                      prefix=config.prefix_steps, obs_layout=obs_spec.layout(stores[0].meta.features))
    instructions = _instructions(config, stores, sources, ends, train_eps)
    if instructions is not None:
        spec = replace(spec, vocab=instructions.tokenizer.vocab_size, max_tokens=instructions.tokenizer.max_tokens)
    data = TrainingData(_normalized_obs(obs, obs_norm), action, base, ends, labelled, train_eps, val_eps, obs_spec,
                        obs_norm, _UNIT, relative, spec, images, sources, chunks, instructions, tuple(config.mix))
    if targets:
        data.aux_keys = targets
        raw_aux = _join([p.aux for p in parts])
        data.aux_norm = MinMaxNormalizer.fit(raw_aux[frames])
        data.aux = _normalized_obs(raw_aux, data.aux_norm)
        data.spec = replace(spec, aux_dim=raw_aux.shape[1])
    data.action_norm = _fit_action_normalizer(data)  # its windows are read unnormalised
    return data


def _instructions(config: TrainConfig, stores: Sequence[EpisodeStore], sources: Sequence[Source], ends: np.ndarray,
                  train_eps: np.ndarray) -> Instructions | None:
    """The episodes' instructions when the policy is conditioned on them: ``config.instructions``, or
    (None) when the training episodes hold more than one; every training episode must then have one."""
    texts = episode_instructions(stores)
    trained = sorted({texts[i] for i in train_eps})
    init = text_config(config.text).init  # a pretrained text encoder turns conditioning on
    if config.instructions is False and init:
        raise DemoError("--text-opt", f"init={init} starts an instruction encoder, and --no-instructions trains without one")
    if config.instructions is False or (config.instructions is None and not init and len(set(trained) - {""}) < 2):
        return None
    if "" in trained:
        i = next(int(i) for i in train_eps if not texts[i])
        source = next(s for s in sources if s.first_episode <= i < s.first_episode + s.episodes)
        raise DemoError(source.path, f"episode {i - source.first_episode} has no instruction, and the policy follows "
                                     "instructions: collect with --instruction, or train with --no-instructions")
    if init:
        pretrained = pretrained_text(init)
        return Instructions.of(pretrained.tokenizer, texts, ends, pretrained)
    return Instructions.of(InstructionTokenizer.train(trained), texts, ends)


def aux_keys(given: str, stores: Sequence[EpisodeStore], obs_spec: ObsSpec) -> tuple[str, ...]:
    """``--aux-target``'s comma-separated keys, each a low-dim feature of every store; refused (DemoError) for a
    policy without cameras (it could read the state itself) or a key a store lacks."""
    keys = tuple(k.strip() for k in given.split(",") if k.strip())
    if not obs_spec.images:
        raise DemoError("--aux-target", "asks the camera encoders for a state, and this policy reads no camera "
                                        "(train on a store with cameras, or give the state as an observation)")
    if not keys:
        raise DemoError("--aux-target", f"names no key (got {given!r}); e.g. --aux-target obs.object_pos")
    for store in stores:
        features = store.meta.features
        for key in keys:
            if key not in features or key.startswith(IMAGE_PREFIX):
                low_dim = sorted(k for k in features if k.startswith("obs.") and not k.startswith(IMAGE_PREFIX))
                raise DemoError(store.path, f"has no low-dim observation {key!r} for --aux-target (it has: {', '.join(low_dim)})")
    return keys


def _flattened(arrays: dict[str, np.ndarray], keys: Sequence[str]) -> np.ndarray:
    """``[N, D]``: the frames of ``keys``, each flattened per frame, side by side (float32). Not ``ObsSpec.concat``:
    a quaternion target stays a quaternion."""
    return np.concatenate([np.asarray(arrays[k], np.float32).reshape(len(arrays[k]), -1) for k in keys], axis=1)


def _join(arrays: list[np.ndarray]) -> np.ndarray:
    """``arrays`` one after another (the one array itself, uncopied, when there is one)."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def split_episodes(store: EpisodeStore, config: TrainConfig, among: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation episode indices (disjoint, sorted), from ``among`` (default: all)."""
    candidates = store.select(config.train_mask) if config.train_mask else np.arange(store.num_episodes)
    if among is not None:
        candidates = np.intersect1d(candidates, among)
    if not config.include_failures and store.num_episodes:
        ok = store.column("success").astype(bool)
        candidates = candidates[ok[candidates]]
    if config.val_mask:
        val = np.intersect1d(store.select(config.val_mask), np.arange(store.num_episodes))
        train = np.setdiff1d(candidates, val)
    else:
        n_val = int(round(config.val_fraction * len(candidates)))
        if config.val_fraction > 0 and len(candidates) >= 4:
            n_val = max(1, n_val)
        perm = np.random.default_rng([config.seed, 0x5E1]).permutation(len(candidates))
        val = np.sort(candidates[perm[:n_val]])
        train = np.sort(candidates[perm[n_val:]])
    if len(train) == 0:
        raise DemoError(store.path, "has no episodes left to train on (check --train-mask/--val-mask/--include-failures)")
    return train, np.sort(val)


def frame_indices(ends: np.ndarray, episodes: np.ndarray) -> np.ndarray:
    """Indices of every frame of ``episodes`` (ends: cumulative episode ends)."""
    starts = np.concatenate([[0], ends[:-1]])
    return np.concatenate([np.arange(starts[i], ends[i]) for i in episodes]) if len(episodes) else np.zeros(0, np.int64)


def _chunk_rows(chunks: np.ndarray | None, n: int, horizon: int, dim: int) -> np.ndarray:
    """``[n, horizon, A]`` chunk labels: ``chunks`` padded with NaN steps to ``horizon``, or all NaN."""
    out = np.full((n, horizon, dim), np.nan, np.float32)
    if chunks is not None:
        out[:, : chunks.shape[1]] = chunks
    return out


class StoreArrays(NamedTuple):
    """One store's frames as training reads them, unnormalised; every per-frame array has the store's frames."""

    obs: np.ndarray  # [N, obs_dim] float32: the chosen low-dim keys concatenated (ObsSpec)
    action: np.ndarray  # [N, A] float32
    base: np.ndarray | None  # [N, ...]: the relative-action base per frame (None for absolute actions)
    ends: np.ndarray  # [E] int: one past each episode's last frame
    labelled: np.ndarray | None  # [N] bool: DAgger's expert-label flags (None: labelled throughout)
    images: dict[str, np.ndarray]  # camera key -> [N, H, W, 3] uint8
    chunks: np.ndarray | None  # [N, H, A] float32: chunk labels, NaN where a frame has none
    aux: np.ndarray | None  # [N, D] float32: the --aux-target keys flattened side by side


def _load_arrays(store: EpisodeStore, obs_spec: ObsSpec, relative: RelativeActions | None, targets: Sequence[str] = ()) -> StoreArrays:
    """One store's arrays for training (:class:`StoreArrays`), read in one pass; ``targets`` are the
    ``--aux-target`` keys."""
    flags = [k for k in (LABEL_KEY, CHUNK_KEY, HAS_CHUNK_KEY) if k in store.meta.features]
    base_key = [relative.obs_key] if relative is not None else []
    keys = list(dict.fromkeys([*obs_spec.source_keys, *obs_spec.images, "action", *flags, *base_key, *targets]))
    arrays, ends = store.load(keys)
    labelled = arrays[LABEL_KEY].reshape(-1).astype(bool) if LABEL_KEY in arrays else None
    action = np.asarray(arrays["action"], dtype=np.float32)
    base = relative.base(arrays, action.shape[1]) if relative is not None else None
    images = {k: np.ascontiguousarray(arrays[k], dtype=np.uint8) for k in obs_spec.images}
    chunks = None
    if CHUNK_KEY in arrays and HAS_CHUNK_KEY in arrays:  # NaN marks a frame without one from here on
        chunks = np.asarray(arrays[CHUNK_KEY], dtype=np.float32).copy()
        chunks[arrays[HAS_CHUNK_KEY].reshape(-1) == 0] = np.nan
    aux = _flattened(arrays, targets) if targets else None
    return StoreArrays(obs_spec.concat(arrays), action, base, ends, labelled, images, chunks, aux)


def _normalized_obs(obs: np.ndarray, norm: MinMaxNormalizer) -> np.ndarray:
    return np.clip(norm.normalize(obs), -OBS_CLIP, OBS_CLIP)  # as the actor does in rollouts


def _fit_action_normalizer(data: TrainingData) -> MinMaxNormalizer:
    """Min-max over every action of every training window (chunk steps included)."""
    lo, hi = chunk_action_limits(data, normalized=False)
    return MinMaxNormalizer.from_limits(lo.min(axis=0), hi.max(axis=0))


def chunk_action_limits(data: TrainingData, normalized: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Per chunk step and action dimension, ``[H, A]`` min and max over the training windows' actions
    (relative to their query frame if so; normalised by ``data.action_norm`` unless ``normalized`` is
    False), read in blocks. Relative targets spread with the step: the first is a step's motion,
    the last a chunk's."""
    windows = Windows(data, data.train_episodes, normalize=False)
    shape = (data.spec.horizon, data.action.shape[1])
    lo, hi = np.full(shape, np.inf, np.float32), np.full(shape, -np.inf, np.float32)
    idx = windows.sampler.indices
    for i in range(0, len(idx), 65536):
        block = windows.actions(idx[i : i + 65536])
        lo, hi = np.minimum(lo, block.min(axis=0)), np.maximum(hi, block.max(axis=0))
    if normalized:  # an increasing affine map per dimension keeps min and max
        lo, hi = data.action_norm.normalize(lo), data.action_norm.normalize(hi)
    return lo, hi


class Windows:
    """Training windows of some episodes as tensors: the WindowSampler on in-memory arrays, then
    actions made relative to the query frame (if so) and normalised, a few array operations per batch."""

    def __init__(self, data: TrainingData, episodes: np.ndarray, normalize: bool = True):
        partial = data.labelled is not None and not data.labelled.all()
        # The label flag rides along as an extra action column, so one gather serves both.
        action = np.concatenate([data.action, data.labelled[:, None].astype(np.float32)], axis=1) if partial else data.action
        self.cameras = list(data.images)
        self.sampler = WindowSampler({"obs": data.obs, **data.images, "action": action}, data.ends, ["obs", *self.cameras],
                                     "action", data.spec.n_obs, data.spec.horizon, episodes=episodes)
        if data.labelled is not None:
            self.sampler.indices = self.sampler.indices[data.labelled[self.sampler.indices]]
        self.partial = partial
        self.base = data.base
        self.norm = data.action_norm if normalize else None
        self.chunks = data.chunks
        self.has_chunk = None if data.chunks is None else np.isfinite(data.chunks[:, 0, 0])
        self.instructions = data.instructions
        self.aux = data.aux
        # --mix: per store, its windows (by query frame) and the share of each batch drawn from them
        self.mix: list[tuple[float, np.ndarray]] = []
        if data.mix and len(data.sources) > 1:
            starts = np.concatenate([[0], data.ends[:-1]])
            for source, weight in zip(data.sources, data.mix):
                if not source.episodes:  # an empty store: no windows to draw
                    self.mix.append((weight, self.sampler.indices[:0]))
                    continue
                lo, hi = starts[source.first_episode], data.ends[source.first_episode + source.episodes - 1]
                self.mix.append((weight, self.sampler.indices[(self.sampler.indices >= lo) & (self.sampler.indices < hi)]))

    def __len__(self) -> int:
        return len(self.sampler)

    def _targets(self, t: np.ndarray, action: np.ndarray, pad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The sampler's action windows at ``t`` as targets: label flags split off, chunk labels in place of
        the executed actions where a query frame has one, relative if so."""
        if self.partial:
            action, pad = action[..., :-1], pad | (action[..., -1] < 0.5)
        if self.has_chunk is not None and self.has_chunk[t].any():
            rows = np.flatnonzero(self.has_chunk[t])
            labels = self.chunks[t[rows], : action.shape[1]]  # [R, <= H, A]; NaN steps past the label's own
            steps = labels.shape[1]
            action, pad = np.array(action), np.array(pad)
            action[rows, :steps] = np.nan_to_num(labels)
            pad[rows] = True
            pad[rows, :steps] = ~np.isfinite(labels[..., 0])
        if self.base is not None:
            action = action - self.base[t][:, None, :]
        return action, pad

    def actions(self, t: np.ndarray) -> np.ndarray:
        """``[B, H, A]`` raw actions of the windows at ``t``, relative to their query frame if so (no
        observation or image is read)."""
        t = np.asarray(t, dtype=np.int64)
        return self._targets(t, *self.sampler.actions(t))[0]

    def get(self, t: np.ndarray) -> Batch:
        b = self.sampler.get(t)
        action, pad = self._targets(b.index, b.action, b.action_pad)
        action = self.norm.normalize(action) if self.norm is not None else action
        obs: Observation = torch.from_numpy(b.obs["obs"])
        if self.cameras or self.instructions is not None:
            obs = {STATE: obs, **{k: torch.from_numpy(b.obs[k]) for k in self.cameras}}
        if self.instructions is not None:  # the query frame's (an episode's frames share one)
            obs[INSTRUCTION] = torch.from_numpy(self.instructions.tokens[self.instructions.of_frame[b.index]])
        if self.aux is not None:  # with cameras: obs is a dict
            obs[AUX_TARGET] = torch.from_numpy(self.aux[b.index])
        return obs, torch.from_numpy(np.ascontiguousarray(action)), torch.from_numpy(pad)

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """``batch_size`` windows drawn uniformly (with ``mix``: each store's share of them from its windows)."""
        if not self.mix:
            return self.get(self.sampler.indices[rng.integers(0, len(self.sampler.indices), size=batch_size)])
        weights = np.array([w if len(idx) else 0.0 for w, idx in self.mix])
        if weights.sum() <= 0:
            raise DemoError("--mix", "every store with a weight above 0 has no training windows")
        counts = rng.multinomial(batch_size, weights / weights.sum())
        picks = [idx[rng.integers(0, len(idx), size=n)] for (_, idx), n in zip(self.mix, counts) if n]
        return self.get(np.concatenate(picks))

    def fixed(self, n: int, seed: int) -> Batch | None:
        """Up to ``n`` windows chosen once (validation), or None when there are none."""
        if len(self.sampler) == 0:
            return None
        idx = self.sampler.indices
        if len(idx) > n:
            idx = np.sort(np.random.default_rng(seed).choice(idx, size=n, replace=False))
        return self.get(idx)
