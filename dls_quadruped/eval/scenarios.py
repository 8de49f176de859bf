"""Evaluation scenarios by name (thesis chapter 7).

A scenario says which env it builds, how it runs the policy and what it reports; the command
line (``python -m dls_quadruped.eval``) only looks it up here. A scenario is one ``Scenario``
value, defined in its own module of this package and registered below (thesis 7.1: survival, survival_sweep,
stairs, speed, omni, cot, gait; docs/eval.md); a new one registers with ``SCENARIO_REGISTRY.register``.
"""

from __future__ import annotations

from dls_quadruped.core.registry import Registry
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

SCENARIO_REGISTRY: Registry[Scenario] = Registry("evaluation scenario")
"""Every scenario by name, with its description (``--scenario``'s choices, in this order)."""
for _scenario in (*velocity_tracking.SCENARIOS, survival.SCENARIO, survival.SWEEP_SCENARIO, stairs.SCENARIO,
                  speed.SCENARIO, omni.SCENARIO, cot.SCENARIO, gait.SCENARIO):
    SCENARIO_REGISTRY.register(_scenario.name, _scenario, _scenario.description)

SCENARIOS = SCENARIO_REGISTRY.as_mapping()
"""Every scenario by name: ``name -> Scenario``, a live view of :data:`SCENARIO_REGISTRY`."""
