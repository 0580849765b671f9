"""The step-cost measurement returns consistent figures (not a speed assertion)."""

from __future__ import annotations

from demo.sim.benchmark import step_cost


def test_step_cost_figures():
    r = step_cost("reach", episodes=1, reps=1)
    us = r["us_per_step"]
    assert r["control_steps"] > 5 and r["n_substeps"] == 25
    assert us["physics"] > 0 and us["collect"] > us["physics"]
    assert 0 < r["ratio_collect_to_physics"] < 1
