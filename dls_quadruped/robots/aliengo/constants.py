"""Unitree AlienGo constants: the only place robot facts live.

Every number here comes from published AlienGo data (Unitree's public robot
description); the MJCF in this folder is
generated from the same facts and a test checks the two agree.

Leg order everywhere in the project is FL, FR, RL, RR (the thesis writes LF, RF, LH, RH).
Joint order per leg is (hip, thigh, calf); the 12 actuated joints are stored leg-major.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ASSET_DIR = Path(__file__).resolve().parent
MJCF_PATH = ASSET_DIR / "aliengo.xml"
"""Robot-only MJCF (free-floating base + 12 hinge joints + 12 motors)."""
SCENE_PATH = ASSET_DIR / "scene.xml"
"""Robot + flat ground plane + light, the default simulation scene."""

LEG_NAMES: tuple[str, ...] = ("FL", "FR", "RL", "RR")
NUM_LEGS = 4
JOINTS_PER_LEG = 3
NUM_JOINTS = NUM_LEGS * JOINTS_PER_LEG
JOINT_NAMES: tuple[str, ...] = tuple(f"{leg}_{j}_joint" for leg in LEG_NAMES for j in ("hip", "thigh", "calf"))
FOOT_NAMES: tuple[str, ...] = tuple(f"{leg}_foot" for leg in LEG_NAMES)
"""Names of the foot sites (MuJoCo) and foot frames (Pinocchio), at the sphere centre."""
FOOT_GEOM_NAMES: tuple[str, ...] = tuple(f"{leg}_foot_geom" for leg in LEG_NAMES)
BASE_BODY_NAME = "trunk"
HIP_BODY_NAMES: tuple[str, ...] = tuple(f"{leg}_hip" for leg in LEG_NAMES)

# Side signs per leg: x (+front / -rear), y (+left / -right).
LEG_X_SIGN = np.array([1.0, 1.0, -1.0, -1.0])
LEG_Y_SIGN = np.array([1.0, -1.0, 1.0, -1.0])

# --- masses [kg] ---
BASE_MASS = 13.042
HIP_MASS = 1.993
THIGH_MASS = 0.639
CALF_MASS = 0.267
TOTAL_MASS = BASE_MASS + NUM_LEGS * (HIP_MASS + THIGH_MASS + CALF_MASS)  # 24.638 kg
GRAVITY = 9.81
"""Standard gravity [m/s^2]; the MJCF uses the same value."""
WEIGHT = TOTAL_MASS * GRAVITY
"""m g [N]."""

# --- geometry [m] ---
HIP_OFFSET_X = 0.2399
HIP_OFFSET_Y = 0.051
HIP_OFFSETS_B = np.stack([LEG_X_SIGN * HIP_OFFSET_X, LEG_Y_SIGN * HIP_OFFSET_Y, np.zeros(4)], axis=1)
"""Hip (abduction) joint positions in the base frame, (4, 3) [m]."""
THIGH_OFFSET_Y = 0.083
"""Lateral offset of the thigh joint from the hip joint (outwards) [m]."""
THIGH_LENGTH = 0.25
CALF_LENGTH = 0.25
FOOT_RADIUS = 0.0265
TRUNK_SIZE = (0.647, 0.15, 0.112)
"""Trunk collision box full extents (x, y, z) [m]."""

# --- joints ---
HIP_RANGE = (-1.2217, 1.2217)
THIGH_RANGE = (-0.524, 3.927)
CALF_RANGE = (-2.7751, -0.6458)
JOINT_RANGES = np.array([HIP_RANGE, THIGH_RANGE, CALF_RANGE] * NUM_LEGS)
"""(12, 2) lower/upper joint limits [rad], leg-major."""
HIP_TORQUE_LIMIT = 35.278
THIGH_TORQUE_LIMIT = 35.278
CALF_TORQUE_LIMIT = 44.4
TORQUE_LIMITS = np.array([HIP_TORQUE_LIMIT, THIGH_TORQUE_LIMIT, CALF_TORQUE_LIMIT] * NUM_LEGS)
"""(12,) symmetric motor torque limits [N m]."""
NOMINAL_JOINT_POS = np.array([0.0, 0.9, -1.8] * NUM_LEGS)
"""(12,) standing pose (hip, thigh, calf) per leg [rad]."""

# --- locomotion constants ---
HIP_HEIGHT = 0.35
"""Nominal hip (= base) height above the ground [m], used for normalisation and as height reference."""
STANDING_BASE_HEIGHT = (
    THIGH_LENGTH * np.cos(NOMINAL_JOINT_POS[1])
    + CALF_LENGTH * np.cos(NOMINAL_JOINT_POS[1] + NOMINAL_JOINT_POS[2])
    + FOOT_RADIUS
)
"""Base height when standing on flat ground in the nominal joint pose (~0.338 m)."""
BASE_HEIGHT_TARGET = STANDING_BASE_HEIGHT
"""Desired base height above flat ground [m] (~0.337 m), the one height target of every controller: the RL
reward's proprioceptive target is ``BASE_HEIGHT_TARGET - FOOT_RADIUS`` (base above the stance feet's sphere
centres, ~0.311 m; ``envs/mdp/rewards.base_height``) and the MPC's CoM reference is ``BASE_HEIGHT_TARGET``
plus the CoM's z offset in the base frame (~0.324 m; ``mpc.srbd.com_height_reference``)."""
MU = 0.5
"""Friction coefficient assumed by the controllers (the simulator uses its own)."""
