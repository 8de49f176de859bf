"""``survival``: the survival task of thesis 7.1.3 (Fig. 18).

The simple-task command (``velocity_tracking.simple_commands``: v_x in [0.3, 0.6] m/s, v_y in
[-0.2, 0.2] m/s, omega_z in [-0.5, 0.5] rad/s, mirrored pairs) on very uneven terrain with
disturbances beyond the rough task's "high" ones:

* terrain: the rough task's non-flat types (``tasks/rough.yaml``: rugged, slopes up/down, boxes,
  stairs up/down), ``ROWS`` rows spanning difficulty ``HARD`` to 1 of the rough task's ranges
  (its hardest 30 %: rugged +-5.9-8 cm, slopes 0.28-0.4, boxes +-11-15 cm, steps 19-25 cm);
  env i starts on column i mod 6 (the scene's spread) and row (i // 6) mod ``ROWS``; a flat
  border of ``BORDER`` m so no robot walks off the world in 15 s;
* events: the rough task's, with ``STRENGTH`` x the half-range of the foot friction (0.2-1.0
  instead of 0.4-0.8), of the constant wrench (+-20 N, +-2 N m) and of the pushes (+-1 m/s),
  pushes twice as often (every 4-6 s); base mass and joint randomisation as rough;
* observation noise: the rough task's ("high", Table 2).

Reported: survival (the episode reaches its 15 s time-out) over all episodes, per terrain type
and per row, each with its 95 % Wilson interval and count; the episode length (time to a fall):
mean with its interval, median and quartiles. No reward: terrain and pushes make it
incomparable with ``simple``'s.

``survival_sweep``: the same commands and terrain types over the rough task's *whole* difficulty
range, ``SWEEP_ROWS`` rows from 0 (nearly flat: rugged +-1 cm, 5 cm steps) to 1 (``survival``'s
hardest row), with the rough task's own disturbances (``SWEEP_STRENGTH`` = 1: friction 0.4-0.8,
+-10 N, pushes of +-0.5 m/s every 8-12 s), reported as survival per row and the difficulty where
it first drops below 50 % (with a 95 % interval). Where every expert is near 0 % on ``survival``
(a few per cent at most, docs/experiments/experts.md Fig. 18), this says how far below that each one still stands. With
``survival``'s doubled disturbances the sweep is at the floor too (docs/experiments/experts.md, Fig. 18b).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from dls_quadruped.envs.config import load_task
from dls_quadruped.eval import metrics as M
from dls_quadruped.eval import sweep as S
from dls_quadruped.eval.scenario import EvalOptions, Scenario, replace_sections
from dls_quadruped.eval.velocity_tracking import flat_task, simple_commands
from dls_quadruped.sim.terrain import TerrainConfig

ROWS = 4
"""Terrain rows (difficulty levels) of the survival terrain."""
HARD = 0.7
"""Easiest row's difficulty, as a fraction of the rough task's range (the hardest row is 1)."""
BORDER = 10.0
"""[m] flat border around the tiles."""
STRENGTH = 2.0
"""Factor on the rough task's half-ranges of friction, wrench and push, and on the push rate."""
SWEEP_ROWS = 8
"""Rows of ``survival_sweep``: difficulty 0, 1/7, ..., 1 of the rough task's ranges."""
SWEEP_STRENGTH = 1.0
"""Disturbance factor of ``survival_sweep``: the rough task's own."""
DIFFICULTY_FIELDS = ("rugged_amplitude", "slope", "box_height", "step_height")


def _lerp(rng, t: float) -> float:
    return float(rng[0] + t * (rng[1] - rng[0]))


def _widen(rng, k: float) -> list[float]:
    """[c - k h, c + k h] of a range [c - h, c + h]."""
    c, h = 0.5 * (rng[0] + rng[1]), 0.5 * (rng[1] - rng[0])
    return [c - k * h, c + k * h]


def survival_terrain(rows: int = ROWS, hard: float = HARD) -> dict:
    """The ``terrain`` section: the rough task's non-flat types over its difficulty ``[hard, 1]``."""
    rough = load_task("rough").data["terrain"]
    default = TerrainConfig()
    out = {"types": [t for t in rough["types"] if t != "flat"], "num_rows": rows, "border": BORDER}
    for name in DIFFICULTY_FIELDS:
        rng = rough.get(name, getattr(default, name))
        out[name] = [_lerp(rng, hard), _lerp(rng, 1.0)]
    return out


def survival_events(strength: float = STRENGTH) -> dict:
    """The ``events`` section: the rough task's, friction/wrench/push ranges widened ``strength``
    times (0: friction fixed at the range's centre, no wrench, no push), push interval divided by it."""
    ev = copy.deepcopy(load_task("rough").data["events"])
    ev["friction"]["params"]["friction_range"] = _widen(ev["friction"]["params"]["friction_range"], strength)
    for key in ("force_range", "torque_range"):
        ev["wrench"]["params"][key] = _widen(ev["wrench"]["params"][key], strength)
    ev["push"]["params"]["velocity_range"] = _widen(ev["push"]["params"]["velocity_range"], strength)
    if strength > 0:  # 0: no pushes (velocity range [0, 0]), interval left as it is
        ev["push"]["interval_s"] = [t / strength for t in ev["push"]["interval_s"]]
    return ev


def survival_task(commands: np.ndarray, opts: EvalOptions, rows: int = ROWS, hard: float = HARD,
                  strength: float = STRENGTH):
    """The evaluation env of ``simple`` (fixed commands, Table-4 reward, no curriculum) on the
    survival terrain (difficulty ``[hard, 1]`` in ``rows`` rows), with the survival events
    (``strength``) and the rough task's observation noise."""
    rough = load_task("rough")
    return replace_sections(flat_task(commands, opts), {
        "terrain": survival_terrain(rows, hard), "events": survival_events(strength),
        "observations": copy.deepcopy(rough.data["observations"]),
    }, source="<eval: survival terrain and disturbances>")


def start_rows(num_envs: int, num_cols: int, rows: int = ROWS) -> np.ndarray:
    """(num_envs,) row of each env: (i // num_cols) mod rows, so every (row, column) tile is used."""
    return (np.arange(num_envs) // num_cols) % rows


def evaluate(policy_path: Path, opts: EvalOptions) -> dict:
    """The ``survival`` scenario: rows ``ROWS``, difficulty ``[HARD, 1]``, disturbances ``STRENGTH``."""
    return _evaluate(policy_path, opts, NAME, DESCRIPTION, ROWS, HARD, STRENGTH)


def evaluate_sweep(policy_path: Path, opts: EvalOptions) -> dict:
    """The ``survival_sweep`` scenario: ``SWEEP_ROWS`` rows over difficulty ``[0, 1]``, disturbances
    ``SWEEP_STRENGTH``, and the difficulty where survival first drops below 50 %."""
    res = _evaluate(policy_path, opts, SWEEP_NAME, SWEEP_DESCRIPTION, SWEEP_ROWS, 0.0, SWEEP_STRENGTH)
    d = np.array([r["rough_difficulty"] for r in res["per_row"]])
    cells = [r["survival"] for r in res["per_row"]]
    rates = np.array([c["rate"] for c in cells], dtype=float)  # NaN for an empty row
    res["survival_crossing_50"] = {
        "rough_difficulty": M.threshold_crossing(d, rates, 0.5),
        "ci95": M.crossing_interval(d, [c["k"] for c in cells], [c["n"] for c in cells], 0.5),
        "note": "fraction of the rough task's terrain difficulty where survival first drops below 50 %"}
    return res


def _evaluate(policy_path: Path, opts: EvalOptions, name: str, description: str, rows: int, hard: float,
              strength: float) -> dict:
    cmd = simple_commands(opts.episodes, opts.seed)
    task = survival_task(cmd, opts, rows, hard, strength)
    types = task.data["terrain"]["types"]
    rec, facts = S.run(task, policy_path, opts, len(cmd), [], rows=start_rows(len(cmd), len(types), rows))
    col, row = facts["terrain_types"], facts["terrain_levels"]
    terrain = {k: v for k, v in task.data["terrain"].items()}
    difficulty = [hard + (1 - hard) * r / max(rows - 1, 1) for r in range(rows)]
    return {**S.header(name, description, policy_path, opts, rec, opts.episodes, 1),
            "disturbance_strength": strength,
            "terrain": terrain, "events": task.data["events"],
            "observation_noise_scale": task.data["observations"]["policy"]["noise_scale"],
            "survival": S.survival_of(rec)[0],
            "length_s": {"mean": M.mean_ci(rec.length * rec.step_dt),
                         "quartiles": M.median_iqr(rec.length * rec.step_dt)},
            "per_type": {t: s for t, s in zip(types, S.survival_of(rec, col, len(types)))},
            "per_row": [{"row": r, "rough_difficulty": d, **{f: _lerp(terrain[f], r / max(rows - 1, 1))
                                                             for f in DIFFICULTY_FIELDS}, "survival": s}
                        for r, (d, s) in enumerate(zip(difficulty, S.survival_of(rec, row, rows)))],
            "per_episode": {"command": rec.command.round(4).tolist(), "terrain_type": [types[c] for c in col],
                            "row": row.tolist(), "fell": rec.fell.astype(bool).tolist(),
                            "length_s": (rec.length * rec.step_dt).round(3).tolist()}}


def _bars(ax, labels, cells, title):
    r = np.array([100 * c["rate"] for c in cells])
    lo = np.array([100 * c["ci95"][0] for c in cells])
    hi = np.array([100 * c["ci95"][1] for c in cells])
    ax.bar(range(len(cells)), r, yerr=S.yerr(r, lo, hi), capsize=3)
    ax.set_xticks(range(len(cells)), labels, fontsize=7, rotation=20)
    ax.set_ylim(0, 105)
    ax.set_ylabel("survival [%] (95 % Wilson)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, axis="y")


def plot(res: dict, path: Path) -> None:
    plt = S.pyplot()
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
    _bars(ax0, [f"{t}\nn={c['n']}" for t, c in res["per_type"].items()], list(res["per_type"].values()),
          "per terrain type")
    _bars(ax1, [f"row {r['row']}\nd={r['rough_difficulty']:.2f}, n={r['survival']['n']}" for r in res["per_row"]],
          [r["survival"] for r in res["per_row"]], "per row (fraction of the rough task's difficulty)")
    fig.suptitle(f"{res['scenario']}: {Path(res['policy']).name}: {S.pct(res['survival'])}", fontsize=10)
    S.savefig(fig, path)


def summary(res: dict) -> str:
    q = res["length_s"]["quartiles"]
    lines = [f"[eval] {res['scenario']}: {res['policy']}, {res['episodes']} episodes of {res['episode_length_s']:g} s",
             (f"  survival {S.pct(res['survival'])}; episode length median {q['median']:.1f} s "
              f"(IQR {q['q1']:.1f}-{q['q3']:.1f})")]
    lines += [f"  {t:12s} {S.pct(c)}" for t, c in res["per_type"].items()]
    lines += [f"  row {r['row']} (d = {r['rough_difficulty']:.2f}) {S.pct(r['survival'])}" for r in res["per_row"]]
    if "survival_crossing_50" in res:
        c = res["survival_crossing_50"]
        lines.append(f"  survival drops below 50 % at difficulty {c['rough_difficulty']:.2f} "
                     f"(95 % CI {c['ci95'][0]:.2f}-{c['ci95'][1]:.2f})")
    return "\n".join(lines)


NAME = "survival"
DESCRIPTION = ("thesis 7.1.3 survival task: simple-task commands on the rough terrains' hardest rows, stronger "
               "pushes and friction spread than rough (Fig. 18)")
SCENARIO = Scenario(NAME, DESCRIPTION, evaluate, plot, default_episodes=96, summary=summary, episodes_multiple=2)

SWEEP_NAME = "survival_sweep"
SWEEP_DESCRIPTION = ("survival-task commands over the rough terrains' whole difficulty range (8 rows) with the "
                     "rough task's disturbances: survival per difficulty and where it drops below 50 %")
SWEEP_SCENARIO = Scenario(SWEEP_NAME, SWEEP_DESCRIPTION, evaluate_sweep, plot, default_episodes=96, summary=summary,
                          episodes_multiple=2)
