"""Self-collision: the legs collide with each other and with the trunk, parent-child pairs do not,
and the contact sensors keep reporting ground contacts only."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from dls_quadruped.robots.aliengo import constants as C


def _scene() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))


def _robot_geoms(m: mujoco.MjModel) -> np.ndarray:
    """Ids of the robot's collision geoms (every geom not on the world body that can collide)."""
    return np.flatnonzero((m.geom_bodyid != 0) & (m.geom_contype != 0))


def _leg_body_ids(m: mujoco.MjModel, leg: str) -> set[int]:
    return {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{leg}_{link}") for link in ("hip", "thigh", "calf")}


def _squeeze_front_legs(m: mujoco.MjModel, seconds: float = 2.0) -> tuple[float, float]:
    """Float the robot without gravity and swing both front hips slowly inward, past each other.

    A joint PD (kp 60 N m/rad, kd 2 N m s/rad) tracks the home pose with the FL hip ramping to
    -1.2 rad and the FR hip to +1.2 rad over ``seconds`` (both legs turn towards the body's
    midline; at those angles the feet would end about 0.25 m on the other side).

    Returns:
        (final FL foot y - FR foot y [m] in the trunk frame, deepest FL-FR leg penetration [m]).
    """
    m.opt.gravity[:] = 0.0
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    d.qpos[2] = 1.0  # far from the floor
    q_home = d.qpos[7:].copy()
    fl_hip, fr_hip = C.JOINT_NAMES.index("FL_hip_joint"), C.JOINT_NAMES.index("FR_hip_joint")
    fl_bodies, fr_bodies = _leg_body_ids(m, "FL"), _leg_body_ids(m, "FR")
    fl_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "FL_foot")
    fr_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "FR_foot")
    trunk = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    deepest = 0.0
    steps = int(seconds / m.opt.timestep)
    for k in range(steps):
        q_ref = q_home.copy()
        ramp = min(1.0, 1.5 * k / steps)  # reach the target at 2/3 of the run, then push
        q_ref[fl_hip], q_ref[fr_hip] = -1.2 * ramp, 1.2 * ramp
        d.ctrl[:] = 60.0 * (q_ref - d.qpos[7:]) - 2.0 * d.qvel[6:]
        mujoco.mj_step(m, d)
        for c in d.contact[: d.ncon]:
            bodies = {int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])}
            if bodies & fl_bodies and bodies & fr_bodies:
                deepest = min(deepest, float(c.dist))
    R = d.xmat[trunk].reshape(3, 3)
    dy = (R.T @ (d.site_xpos[fl_site] - d.site_xpos[fr_site]))[1]
    return float(dy), deepest


def test_front_legs_driven_into_each_other_stop():
    dy, deepest = _squeeze_front_legs(_scene())
    # the feet stay on their own side (FL left of FR) and the legs barely interpenetrate
    assert dy > 0.0
    assert deepest > -0.01


def test_without_self_collision_the_same_legs_pass_through():
    """The control experiment: with the robot's conaffinity cleared the legs cross (the test above can fail)."""
    m = _scene()
    m.geom_conaffinity[_robot_geoms(m)] = 0
    dy, _ = _squeeze_front_legs(m)
    assert dy < -0.1


def test_no_self_contact_in_the_home_pose_and_parent_child_pairs_filtered():
    m = _scene()
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    d.qpos[2] = 1.0
    mujoco.mj_forward(m, d)
    assert d.ncon == 0  # no leg touches the trunk or another leg when standing
    # thigh and calf capsules of one leg overlap at the knee, and MuJoCo filters the pair
    assert not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    assert np.all(m.geom_conaffinity[_robot_geoms(m)] == 1)


def test_leg_on_trunk_contact_is_not_a_base_contact():
    """A calf pressed onto the trunk must not trip the trunk's ground-contact sensor (terminations)."""
    m = _scene()
    m.opt.gravity[:] = 0.0
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    d.qpos[2] = 1.0
    d.qpos[7:10] = [1.044, 3.09, -2.764]  # FL thigh swung up and back, foot pressed onto the trunk
    mujoco.mj_forward(m, d)
    trunk_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "trunk_geom")
    touching = [c for c in d.contact[: d.ncon] if trunk_geom in (c.geom1, c.geom2)]
    assert touching and min(c.dist for c in touching) < 0.0  # the pose does put the foot into the trunk
    adr = m.sensor_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, "trunk_contact")]
    assert d.sensordata[adr] == 0.0


def test_foot_contact_takes_the_foot_friction_whatever_the_ground():
    """Friction randomisation writes the feet only: with priority 1 the foot's coefficient is the contact's."""
    m = _scene()
    foot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, C.FOOT_GEOM_NAMES[0])
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    assert m.geom_priority[foot] > m.geom_priority[floor]
    m.geom_friction[foot, 0], m.geom_friction[floor, 0] = 0.42, 1.7
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    d.qpos[2] -= d.geom_xpos[foot, 2] - C.FOOT_RADIUS + 0.001  # the foot 1 mm into the floor
    mujoco.mj_forward(m, d)
    mus = [c.friction[0] for c in d.contact[: d.ncon] if foot in (c.geom1, c.geom2)]
    assert mus and all(mu == pytest.approx(0.42) for mu in mus)
