"""Imitation-learning algorithms over the trainer core (:mod:`demo.training`).

- :mod:`.bc`: behaviour cloning of any registered policy (MLP, diffusion, ACT): supervised training.
- :mod:`.dagger`: DAgger and HG-DAgger (rollouts, aggregation, beta schedule, label accounting) and
  the :class:`Family` plugin its relatives implement: :mod:`.safedagger`, :mod:`.aggrevate`,
  :mod:`.dart`, :mod:`.perturb`.
- :mod:`.distill`: a diffusion policy distilled into a one-step student.
"""
