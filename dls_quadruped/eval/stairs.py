"""``stairs``: climbing success vs step height, 5-50 cm (thesis Fig. 19, the staircase test).

Terrain: one column of ``stairs_up`` tiles (the climb task's stairs: 30 cm treads, the spawn
platform at the bottom), one row per height of ``HEIGHTS`` (rows interpolate the heights
linearly, so the grid must be evenly spaced), ``TILE`` m tiles: ``STEPS`` steps from the
platform to the top, which joins a ``BORDER`` m flat border at the top level. Every robot
starts on its tile's platform facing +y (along the column, towards the border: no neighbouring
tile in its way) and is commanded (v_x, 0, 0), v_x ~ U[0.3, 0.5] m/s (the climb task's forward
range), for 15 s; no observation noise and no perturbation (the climb task's low ones would mix
robustness into a geometry test). Per height (``--episodes`` each), with 95 % intervals:

* ``success``: the base reached the top level (terrain height under the base centre = the top)
  before the episode ended (Wilson);
* ``survival``: the episode reached its time-out (Wilson);
* ``climbed``: the highest terrain level the base reached above the platform, as a fraction of
  the flight (STEPS x h) (mean over episodes).

Thesis: "the performances dropped off after only 25 cm, even for the climb task".
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.scenario import EvalOptions, Scenario, replace_sections
from dls_quadruped.eval.velocity_tracking import flat_task

HEIGHTS = tuple(round(0.05 * k, 2) for k in range(1, 11))
"""[m] step heights 0.05 ... 0.50 (Table 3, climb)."""
SPEED_RANGE = (0.3, 0.5)
"""[m/s] forward command range (Table 3, climb)."""
TILE = 6.0
"""[m] tile side: (6 - 2) / 2 / 0.3 -> 6 steps, the top 2.5 m from the spawn point (reachable in
15 s at 0.3 m/s with slack; the climb task's 8 m tiles put it at 4 m)."""
BORDER = 8.0
"""[m] flat border at the top level: a robot at 0.5 m/s stays on it for the rest of the episode."""
YAW = math.pi / 2
"""[rad] start heading: +y, along the single column."""


def stairs_terrain(heights: tuple[float, ...] = HEIGHTS) -> dict:
    """The ``terrain`` section: one ``stairs_up`` column, row r at ``heights[r]``."""
    h = np.asarray(heights, dtype=float)
    if len(h) > 1 and not np.allclose(np.diff(h), h[1] - h[0]):
        raise ValueError(f"stairs: heights must be evenly spaced (rows interpolate linearly), got {list(heights)}")
    return {"types": ["stairs_up"], "num_rows": len(h), "step_height": [float(h[0]), float(h[-1])],
            "tile_size": TILE, "border": BORDER}


def stairs_commands(heights: tuple[float, ...], per: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """((H per, 3) commands (v_x ~ U(SPEED_RANGE), 0, 0), (H per,) height index), height-major."""
    cmd, group = S.repeat_conditions(np.zeros((len(heights), 3)), per)
    cmd[:, 0] = np.random.default_rng(seed).uniform(*SPEED_RANGE, size=len(cmd))
    return cmd, group


def stairs_task(commands: np.ndarray, opts: EvalOptions, heights: tuple[float, ...] = HEIGHTS):
    """The evaluation env of ``simple`` (no noise, no perturbation, fixed commands) on the stairs,
    every robot placed facing +y."""
    task = flat_task(commands, opts)
    reset = {"reset_robot": {"mode": "reset", "params": {"joint_scale": [1.0, 1.0], "yaw": [YAW, YAW]}}}
    return replace_sections(task, {"terrain": stairs_terrain(heights), "events": reset},
                            source="<eval: stairs_up column, one row per step height>")


def climbed_fraction(ground_z: np.ndarray, valid: np.ndarray, start_z: np.ndarray, flight: np.ndarray) -> np.ndarray:
    """(E,) highest terrain level under the base over the valid steps, above ``start_z``, / ``flight``.

    Args:
        ground_z: (T, E) [m]; valid: (T, E); start_z: (E,) [m] platform level; flight: (E,) [m] top - platform.
    """
    top = np.where(valid, ground_z, -np.inf).max(axis=0)
    return np.clip(np.where(np.isfinite(top), top - start_z, 0.0) / flight, 0.0, None)


def reached_top(fraction: np.ndarray, flight: np.ndarray) -> np.ndarray:
    """(E,) success: the climbed fraction (:func:`climbed_fraction`) reached the top level within 1 mm."""
    return np.asarray(fraction) >= 1.0 - 1e-3 / np.asarray(flight)


def steps_per_flight() -> int:
    """Steps from the platform to the top of a ``TILE`` m ``stairs_up`` tile."""
    from dls_quadruped.sim.terrain import TerrainConfig

    return TerrainConfig(tile_size=TILE).num_steps


def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
    cmd, group = stairs_commands(HEIGHTS, opts.episodes, opts.seed)
    task = stairs_task(cmd, opts, HEIGHTS)
    rec, facts = S.run(task, policy_path, opts, len(cmd), ["ground_z"], rows=group)
    steps = steps_per_flight()
    h = np.asarray(HEIGHTS)[group]
    fraction = climbed_fraction(rec.probes["ground_z"], rec.valid, facts["env_origins"][:, 2], steps * h)
    success = reached_top(fraction, steps * h)
    n = len(HEIGHTS)
    rows = [{"step_height": height, "success": s, "survival": v, "climbed_fraction": c}
            for height, s, v, c in zip(HEIGHTS, M.grouped_rate(success, group, n), S.survival_of(rec, group, n),
                                       M.grouped_mean(fraction, group, n))]
    rates = np.array([r["success"]["rate"] for r in rows])
    return {**S.header(NAME, DESCRIPTION, policy_path, opts, rec, opts.episodes, n),
            "terrain": task.data["terrain"], "steps_per_flight": steps, "speed_range": list(SPEED_RANGE),
            "per_height": rows,
            "success_crossing_50": {"step_height": M.threshold_crossing(HEIGHTS, rates, 0.5),
                                    "ci95": M.crossing_interval(HEIGHTS, [r["success"]["k"] for r in rows],
                                                                [r["success"]["n"] for r in rows], 0.5),
                                    "note": "step height where success first drops below 50 %"},
            "per_episode": {"step_height": h.tolist(), "command_v_x": rec.command[:, 0].round(4).tolist(),
                            "climbed_fraction": np.round(fraction, 4).tolist(), "fell": rec.fell.astype(bool).tolist()}}


def plot(res: dict, path: Path) -> None:
    plt = S.pyplot()
    h = 100 * np.array([r["step_height"] for r in res["per_height"]])
    fig, ax = plt.subplots(figsize=(7, 4))
    for key, style in (("success", "-o"), ("survival", "--s")):
        r = np.array([100 * x[key]["rate"] for x in res["per_height"]])
        lo = np.array([100 * x[key]["ci95"][0] for x in res["per_height"]])
        hi = np.array([100 * x[key]["ci95"][1] for x in res["per_height"]])
        ax.errorbar(h, r, yerr=S.yerr(r, lo, hi), fmt=style, capsize=3,
                    label="reached the top" if key == "success" else "survived 15 s")
    c = np.array([100 * x["climbed_fraction"]["mean"] for x in res["per_height"]], dtype=float)
    ax.plot(h, c, ":^", label="mean fraction of the flight climbed")
    ax.axvline(25, color="0.6", lw=1, ls="--", label="thesis: drop after 25 cm")
    ax.set_xlabel("step height [cm]")
    ax.set_ylabel("[%] (95 % Wilson)")
    ax.set_ylim(-5, 105)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"stairs: {Path(res['policy']).name}, {res['episodes_per_condition']} episodes per height, "
                 f"{res['steps_per_flight']} steps, v_x {res['speed_range'][0]:g}-{res['speed_range'][1]:g} m/s",
                 fontsize=9)
    S.savefig(fig, path)


def summary(res: dict) -> str:
    lines = [f"[eval] stairs: {res['policy']}, {res['episodes_per_condition']} episodes x {res['conditions']} heights"]
    for r in res["per_height"]:
        c = r["climbed_fraction"]
        lines.append(f"  h {100 * r['step_height']:4.0f} cm: top {S.pct(r['success'])}, survival "
                     f"{100 * r['survival']['rate']:.0f} %, climbed {100 * c['mean']:.0f} % of the flight")
    return "\n".join(lines)


NAME = "stairs"
DESCRIPTION = "step-height sweep 5-50 cm up a 6-step stairs_up flight, 0.3-0.5 m/s forward: reached the top (Fig. 19)"
SCENARIO = Scenario(NAME, DESCRIPTION, evaluate, plot, default_episodes=12, summary=summary)
