"""Swing-foot tracking against a moving touch-down target.

``python -m dls_quadruped.bench.swing [--vx 0.5] [--bandwidth 40]`` walks the model-based baseline
(trot + heuristic footholds + naive-warm-started force MPC, ``mpc.baseline``) on flat ground and
records, every physics step (200 Hz), the swing legs' foot position against

* the swing reference of that step (``LowLevelController.p_ref_w``): tracking error while swinging;
* the touch-down target at the first stance step after a swing: touch-down error.

``--bandwidth`` sets ``LowLevelConfig.target_bandwidth`` (0: no target tracker, the reference aims at
the raw target as if it stood still). Prints and writes JSON (``--out``).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import torch

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.control.lowlevel import LowLevelConfig
from dls_quadruped.core.progress import progress
from dls_quadruped.mpc.baseline import BaselineConfig, ModelBasedBaseline
from dls_quadruped.mpc.config import SamplerConfig
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def measure(vx: float = 0.5, seconds: float = 6.0, samples: int = 10_000, bandwidth: float = 0.0,
            settle_s: float = 1.0, seed: int = 0) -> dict:
    """Swing tracking and touch-down errors [m] of one robot walking at ``vx`` (statistics after ``settle_s``)."""
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    cfg = BaselineConfig(sampler=SamplerConfig(num_samples=samples))
    decimation = round(cfg.sampler.mpc_period / model.opt.timestep)
    ctrl = ModelBasedBaseline(1, cfg, seed=seed)
    cmd = torch.tensor([[vx, 0.0, 0.0]])
    sim_cfg = SimConfig(num_workers=0, control=replace(LowLevelConfig(), target_bandwidth=bandwidth))
    track, touch, touch_xy, speed = [], [], [], []
    fallen = False
    with make_backend("cpu", model, 1, sim_cfg) as sim:
        controller = sim.in_process_shard.controller  # num_workers=0: read its swing reference
        state = sim.reset(torch.arange(1), **home_state(1, seed, 0.0))
        was_swing = np.zeros(4, dtype=bool)
        for k in progress(range(round(seconds / cfg.sampler.mpc_period)), desc=f"v_x {vx:g} m/s", unit="MPC step",
                          leave=False):
            result, _ = ctrl.step(state, cmd)
            sim.set_references(result.f, result.d, result.foot_target_w, result.force_w)
            for _ in range(decimation):
                foot = state.foot_pos_w[0].double().numpy()  # the state the controller acts on
                state = sim.step(1)
                swing = ~controller.contact[0].numpy()
                if state.time[0].item() > settle_s:
                    err = np.linalg.norm(foot - controller.p_ref_w[0].numpy(), axis=-1)
                    track.extend(err[swing])
                    landed = was_swing & ~swing  # first stance step after a swing
                    target = result.foot_target_w[0].double().numpy()
                    touch.extend(np.linalg.norm(foot - target, axis=-1)[landed])
                    touch_xy.extend(np.linalg.norm((foot - target)[:, :2], axis=-1)[landed])
                was_swing = swing
            fallen |= bool((state.base_contact | state.diverged)[0])
            if k * cfg.sampler.mpc_period > settle_s:
                speed.append(float(state.base_lin_vel_w[0, 0]))
    track, touch, touch_xy = np.asarray(track), np.asarray(touch), np.asarray(touch_xy)
    return {"vx_command": vx, "seconds": seconds, "samples": samples, "target_bandwidth": bandwidth,
            "mean_vx": float(np.mean(speed)), "fallen": fallen,
            "swing_tracking_rms_m": _rms(track), "swing_tracking_max_m": float(track.max()),
            "touch_down_rms_m": _rms(touch), "touch_down_max_m": float(touch.max()),
            "touch_down_xy_rms_m": _rms(touch_xy), "touch_downs": int(touch.size)}


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vx", type=float, default=0.5)
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--bandwidth", type=float, default=LowLevelConfig().target_bandwidth,
                        help="LowLevelConfig.target_bandwidth [rad/s]; 0 = target treated as at rest")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    out = measure(args.vx, args.seconds, args.samples, args.bandwidth)
    text = json.dumps(out, indent=2)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    return out


if __name__ == "__main__":
    run_cli(main)  # a bad flag or a user error: one line, exit 2; Ctrl-C: one line, exit 130
