"""Evaluation scenarios by name (thesis chapter 7).

A scenario says which env it builds, how it runs the policy and what it reports; the command
line (``python -m dls_quadruped.eval``) only looks it up here. A scenario is one ``Scenario``
value, defined in its own module of this package and listed below (thesis 7.1: survival, survival_sweep, stairs,
speed, omni, cot, gait; docs/eval.md).
"""

from __future__ import annotations

from dls_quadruped.eval import (
                                                      cot,
                                                      gait,
                                                      omni,
                                                      speed,
                                                      stairs,
                                                      survival,
                                                      velocity_tracking,
)
from dls_quadruped.eval.scenario import Scenario

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (*velocity_tracking.SCENARIOS, survival.SCENARIO,
                                                      survival.SWEEP_SCENARIO, stairs.SCENARIO, speed.SCENARIO,
                                                      omni.SCENARIO, cot.SCENARIO, gait.SCENARIO)}
"""Every scenario by name."""
