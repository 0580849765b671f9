"""demo: robot learning from demonstration in MuJoCo.

Collect demonstrations, curate them, convert their actions to one canonical end-effector format,
train policies (behaviour cloning, DAgger, diffusion) and judge them by rollouts in simulation.
"""

__version__ = "0.1.0"
