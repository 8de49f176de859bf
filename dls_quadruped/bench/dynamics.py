"""Per-robot CPU time of ``control.dynamics.LegDynamics.compute``, its parts and the alternatives
measured when it was designed (``python -m dls_quadruped.bench.dynamics``; numbers in the
``control/dynamics.py`` docstring)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dls_quadruped.cli import ArgumentParser, positive_int, run_cli
from dls_quadruped.control.conventions import (
    NV_MJ,
    mujoco_to_pinocchio,
    zero_qacc_acceleration,
)
from dls_quadruped.control.dynamics import LegDynamics
from dls_quadruped.robots.aliengo import constants as C


def timing(batch: int = 1024, repeats: int = 7) -> None:
    """Print the per-robot CPU time of :meth:`LegDynamics.compute`, its parts and alternatives."""
    import time

    rng = np.random.default_rng(0)
    qpos = np.tile(np.r_[0.0, 0.0, C.STANDING_BASE_HEIGHT, 1.0, 0.0, 0.0, 0.0, C.NOMINAL_JOINT_POS], (batch, 1))
    qpos[:, 3:7] += 0.1 * rng.standard_normal((batch, 4))
    qpos[:, 7:] += 0.2 * rng.standard_normal((batch, C.NUM_JOINTS))
    qvel = rng.standard_normal((batch, NV_MJ))
    dyn = LegDynamics()
    dyn.compute(qpos, qvel)
    m, d = dyn.model, dyn.data
    q, v = mujoco_to_pinocchio(qpos, qvel)
    a0 = zero_qacc_acceleration(v)
    feet = [m.getFrameId(name) for name in C.FOOT_NAMES]
    pool2 = pin.ModelPool(m, 2)
    LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

    def best(fn, wall: bool = False) -> float:  # CPU time (robust to other processes), best of N
        clock = time.perf_counter if wall else time.process_time
        fn()
        times = []
        for _ in range(repeats):
            t0 = clock()
            fn()
            times.append(clock() - t0)
        return min(times) / batch * 1e6

    def pin_loop() -> None:  # the loop inside compute(), alone
        M_view, J_view, dJ_view = dyn._M_view, dyn._J_view, dyn._dJ_view
        for qi, vi, Mi, Ji, dJi in zip(q, v, dyn._M, dyn._JdJ[:, :6], dyn._JdJ[:, 6:]):
            pin.computeJointJacobiansTimeVariation(m, d, qi, vi)
            pin.crba(m, d, qi)
            Mi[...], Ji[...], dJi[...] = M_view, J_view, dJ_view

    def all_terms() -> None:  # computeAllTerms + reading M, nle, J, dJ (no placements)
        for qi, vi, Mi, Ji, dJi, hi in zip(q, v, dyn._M, dyn._JdJ[:, :6], dyn._JdJ[:, 6:], dyn._h):
            pin.computeAllTerms(m, d, qi, vi)
            Mi[...], Ji[...], dJi[...], hi[...] = d.M, d.J, d.dJ, d.nle

    def per_foot() -> None:  # the naive path: frame Jacobian and classical acceleration per foot
        for qi, vi, ai in zip(q, v, a0):
            pin.forwardKinematics(m, d, qi, vi, ai)
            pin.computeJointJacobians(m, d, qi)
            pin.crba(m, d, qi)
            pin.rnea(m, d, qi, vi, ai)
            for fid in feet:
                pin.getFrameJacobian(m, d, fid, LWA)
                pin.getFrameClassicalAcceleration(m, d, fid, LWA)
                pin.updateFramePlacement(m, d, fid)

    def nle_loop() -> None:
        for qi, vi, hi in zip(q, v, dyn._h):
            hi[...] = pin.nonLinearEffects(m, d, qi, vi)

    rows = [
        ("LegDynamics.compute, total", best(lambda: dyn.compute(qpos, qvel))),
        ("  its Pinocchio loop (jac dot + crba + copies)", best(pin_loop)),
        ("  its rneaInParallel, 1 thread", best(lambda: pin.rneaInParallel(1, dyn._pool, q.T, v.T, a0.T, dyn._h.T))),
        (
            "rneaInParallel, 2 threads (wall clock)",
            best(lambda: pin.rneaInParallel(2, pool2, q.T, v.T, a0.T, dyn._h.T), True),
        ),
        ("nonLinearEffects loop (alternative for h)", best(nle_loop)),
        ("computeAllTerms + reads (alternative)", best(all_terms)),
        ("per-foot frame Jacobian/acceleration path", best(per_foot)),
    ]
    print(f"B = {batch}, CPU us per robot, best of {repeats}")
    for name, us in rows:
        print(f"  {name:48s} {us:6.2f}")


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=positive_int, default=1024, help="robots per call (default 1024)")
    parser.add_argument("--repeats", type=positive_int, default=7, help="timings per row, best kept (default 7)")
    args = parser.parse_args(argv)
    timing(args.batch, args.repeats)


if __name__ == "__main__":
    run_cli(main)  # a bad flag: one line, exit 2
