"""The trainer core that every learning algorithm shares.

- :mod:`.config`: :class:`TrainConfig`, every hyperparameter and where its default comes from.
- :mod:`.data`: store -> split -> normalisers -> windows of observations and action chunks.
- :mod:`.optim`: AdamW, warm-up + cosine, EMA, one optimiser step.
- :mod:`.trainer`: :class:`TrainingRun`, the one run shape: seeding, run directory, resume,
  monitoring rollouts, checkpoints, metrics, summary.
- :mod:`.distributed`: data-parallel training under torchrun.
- :mod:`.plots`: training curves and success-against-setting figures.

Algorithms live above this: :mod:`demo.imitation` (BC, the DAgger family) and :mod:`demo.rl`.
"""
