"""Policies: the networks, what they read and write, and how a trained one is saved and run.

- :mod:`.policy`: the :class:`Policy` interface (loss, sample) and the registry of policy classes by name.
- Networks: :mod:`.mlp` (with its output heads, :mod:`.heads`), :mod:`.diffusion` (with
  :mod:`.unet1d`, :mod:`.denoiser_mlp`, :mod:`.noise_scheduler`), :mod:`.act` (ACT), image
  encoders :mod:`.encoders` in front of any of them (:mod:`.visuomotor`).
- Inputs and outputs: :mod:`.observation` (which store features a policy reads), :mod:`.normalizer`,
  :mod:`.relative` (joint targets relative to the current joints), :mod:`.actions` (a policy's
  action to the env's), :mod:`.actor` (a policy executing in an env: history, chunks, ensembling).
- :mod:`.checkpoint`: a run directory's saved policy (safetensors + JSON), loaded without pickle.
- :mod:`.device`: where a network runs (CPU, CUDA, MPS) and its autocast.

Nothing here trains or rolls out: :mod:`demo.training` and :mod:`demo.evaluation` use these.
"""
