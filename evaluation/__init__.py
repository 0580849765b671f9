"""Judging a trained policy by rollouts: success rate, not loss.

- :mod:`.evaluate`: ``demo eval``: a run's policy rolled out on held-out seeds (in-process, worker
  processes or Ray), Wilson intervals, failure reasons, ``--record`` into a store.
- :mod:`.video`: rollouts rendered to a GIF/MP4.

Training (monitoring rollouts), the DAgger family, the Gymnasium envs and the CLI all use this.
"""
