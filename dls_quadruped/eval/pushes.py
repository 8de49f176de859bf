"""Flat ground with pushes: the simple task's evaluation env with one disturbance, a push.

Every ``interval_s`` (drawn per push from U[a, b] s) the base's horizontal velocity changes by a draw from
U[-P, P] m/s per axis (``envs/mdp/events.push_robot``), on a schedule fixed per episode
(``envs/schedule.py``), so every controller run on the same episodes meets the same pushes. No terrain, no
observation noise, no other event: the experiment of ``docs/experiments/pushes_plan.md`` (does the MPC raise
base's survival?) needs a task where survival has room to move, which the survival task (every controller at
0-10 %) does not give.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from dls_quadruped.eval.scenario import EvalOptions, replace_sections
from dls_quadruped.eval.velocity_tracking import flat_task

PUSH_INTERVAL_S = (4.0, 6.0)
"""[s] time between two pushes, drawn per push (the survival task's interval)."""


def check_push_speed(push_speed) -> float:
    """``push_speed`` as a float, or a ValueError naming what is allowed (a finite number > 0 [m/s])."""
    ok = isinstance(push_speed, (int, float)) and not isinstance(push_speed, bool) and math.isfinite(push_speed)
    if not ok or push_speed <= 0:
        raise ValueError(f"push speed must be a finite number > 0 [m/s], got {push_speed!r}")
    return float(push_speed)


def pushes_task(commands: np.ndarray, opts: EvalOptions, push_speed: float,
                interval_s: tuple[float, float] = PUSH_INTERVAL_S):
    """``flat_task(commands, opts)`` (fixed commands, Table-4 reward, no noise, no curriculum) with pushes of
    up to ``push_speed`` [m/s] per horizontal axis every U[``interval_s``] s."""
    p = check_push_speed(push_speed)
    lo, hi = (float(t) for t in interval_s)
    if not 0 < lo <= hi:
        raise ValueError(f"push interval must be [a, b] s with 0 < a <= b, got {list(interval_s)}")
    task = flat_task(commands, opts)
    events = copy.deepcopy(task.data["events"])
    events["push"] = {"func": "push_robot", "mode": "interval", "interval_s": [lo, hi],
                      "params": {"velocity_range": [-p, p]}}
    return replace_sections(task, {"events": events},
                            source=f"<eval: flat, pushes of up to {p:g} m/s every {lo:g}-{hi:g} s>")
