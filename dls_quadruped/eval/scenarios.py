"""Evaluation scenarios by name (SPEC 10).

A scenario says which env it builds, how it runs the policy and what it reports; the command
line (``python -m dls_quadruped.eval``) only looks it up here. A new scenario (survival, stairs,
speed sweep, ...) is one more ``Scenario`` value, defined in its own module of this package and
listed below.
"""

from __future__ import annotations

from dls_quadruped.eval import velocity_tracking
from dls_quadruped.eval.scenario import Scenario

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (*velocity_tracking.SCENARIOS,)}
"""Every scenario by name."""
