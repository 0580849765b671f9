"""Reinforcement learning and inverse RL on the tasks.

- :mod:`.ppo`: PPO with a Gaussian actor on the Gymnasium envs (:mod:`demo.gym`).
- :mod:`.adversarial`: GAIL and AIRL (a discriminator's reward, PPO as the generator).
- :mod:`.irl_linear`: linear-reward IRL (feature matching).
- :mod:`.rewards`: task rewards and reward features; :mod:`.expert_data`: demonstrations as
  (state, action, next state) transitions.
"""
