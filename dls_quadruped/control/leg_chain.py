"""The leg chains of the robot as a ``mujoco.MjModel`` holds them, and where MuJoCo stores their inertia.

:func:`leg_chain_params` reads and checks the kinematic parameters of the four 3-joint chains (body offsets
and orientations, joint axes, anchors and reference angles, foot-site offsets) so that no robot number is
typed in the batched torch kinematics (``control/foot_kinematics.py``); :func:`qM_addresses_from_pairs`
finds the leg blocks in a sparse inertia of any layout (C MuJoCo's ``data.M``, MuJoCo Warp's CSR ``M``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from dls_quadruped.robots.aliengo import constants as C


@dataclass(frozen=True)
class LegChainParams:
    """Kinematic parameters of the 4 legs read from a ``mujoco.MjModel`` (leg l, chain joint k; float64).

    Attributes:
        body_pos: (4, 3, 3) [m] body k's origin in its parent body's frame (``body_pos``).
        body_rot: (4, 3, 3, 3) body k's orientation in its parent body's frame (``body_quat``).
        axis: (4, 3, 3) unit joint axes in body k's frame (``jnt_axis``).
        anchor: (4, 3, 3) [m] joint anchors in body k's frame (``jnt_pos``).
        qpos0: (4, 3) [rad] joint reference angles (``qpos0``: the body turns by ``q - qpos0``).
        foot: (4, 3) [m] foot-site (sphere centre) position in the calf body's frame (``site_pos``).
        qpos_adr: (4, 3) qpos addresses of the leg joints; dof_adr: (4, 3) their qvel/dof addresses.
        nv: the model's number of dofs.
        qM_adr: (4, 3, 3) addresses of the leg blocks' entries in C MuJoCo's sparse inertia (``data.M``,
            ``data.qM`` before MuJoCo 4; both triangles map to the one stored entry).
    """

    body_pos: np.ndarray
    body_rot: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray
    qpos0: np.ndarray
    foot: np.ndarray
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    nv: int
    qM_adr: np.ndarray


def leg_chain_params(model: mujoco.MjModel) -> LegChainParams:
    """Read and validate the AlienGo layout from a MuJoCo model (robot-only MJCF or a scene).

    The base body ``constants.BASE_BODY_NAME`` must carry the free joint at qpos 0..6 / dofs 0..5;
    leg joints are hinges named ``constants.JOINT_NAMES``, one per body, chained base -> hip ->
    thigh -> calf, at qpos ``7 + i`` and dofs ``6 + i``; the foot sites ``constants.FOOT_NAMES`` sit on
    the calves.

    Raises:
        ValueError: the model does not have that layout.
    """
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, C.BASE_BODY_NAME)
    if base < 0:
        raise ValueError(f"base body {C.BASE_BODY_NAME!r} missing from the model")
    free = model.body_jntadr[base]
    if (model.body_jntnum[base] != 1 or model.jnt_type[free] != mujoco.mjtJoint.mjJNT_FREE
            or model.jnt_qposadr[free] != 0 or model.jnt_dofadr[free] != 0):
        raise ValueError(f"body {C.BASE_BODY_NAME!r} must carry the model's free joint at qpos 0 / dof 0")
    n = C.NUM_LEGS
    body_pos, body_rot = np.zeros((n, 3, 3)), np.zeros((n, 3, 3, 3))
    axis, anchor, qpos0 = np.zeros((n, 3, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3))
    foot = np.zeros((n, 3))
    qpos_adr, dof_adr = np.zeros((n, 3), dtype=np.int64), np.zeros((n, 3), dtype=np.int64)
    for leg in range(n):
        parent = base
        for k in range(3):
            name = C.JOINT_NAMES[3 * leg + k]
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if jid < 0:
                raise ValueError(f"joint {name!r} missing from the model")
            if model.jnt_type[jid] != mujoco.mjtJoint.mjJNT_HINGE:
                raise ValueError(f"joint {name!r} is not a hinge")
            body = model.jnt_bodyid[jid]
            if model.body_parentid[body] != parent or model.body_jntnum[body] != 1:
                raise ValueError(f"joint {name!r} must be the only joint of a child of the previous link of its leg")
            qadr, dadr = int(model.jnt_qposadr[jid]), int(model.jnt_dofadr[jid])
            if qadr != 7 + 3 * leg + k or dadr != 6 + 3 * leg + k:
                raise ValueError(f"joint {name!r} has qpos/dof address {qadr}/{dadr}, expected "
                                 f"{7 + 3 * leg + k}/{6 + 3 * leg + k} (constants.JOINT_NAMES order)")
            body_pos[leg, k] = model.body_pos[body]
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, model.body_quat[body])
            body_rot[leg, k] = rot.reshape(3, 3)
            axis[leg, k] = model.jnt_axis[jid]
            anchor[leg, k] = model.jnt_pos[jid]
            qpos0[leg, k] = model.qpos0[qadr]
            qpos_adr[leg, k], dof_adr[leg, k] = qadr, dadr
            parent = body
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, C.FOOT_NAMES[leg])
        if sid < 0 or model.site_bodyid[sid] != parent:
            raise ValueError(f"foot site {C.FOOT_NAMES[leg]!r} missing or not on the calf body")
        foot[leg] = model.site_pos[sid]
    return LegChainParams(body_pos=body_pos, body_rot=body_rot, axis=axis, anchor=anchor, qpos0=qpos0, foot=foot,
                          qpos_adr=qpos_adr, dof_adr=dof_adr, nv=int(model.nv), qM_adr=_qM_addresses(model, dof_adr))


def _qM_addresses(model: mujoco.MjModel, dof_adr: np.ndarray) -> np.ndarray:
    """(4, 3, 3) addresses in C MuJoCo's sparse inertia (``data.M``; ``data.qM`` before MuJoCo 4) of the leg blocks.

    Found by asking MuJoCo itself: with the sparse inertia ``e_a``, ``mj_fullM`` lights the dense
    entries stored at address a. No assumption on the sparse layout (it changed in MuJoCo 4).
    """
    data = mujoco.MjData(model)
    sparse = data.M if hasattr(data, "M") else data.qM
    dense = np.zeros((model.nv, model.nv))
    rows, cols = [], []
    for a in range(model.nM):
        sparse[:] = 0.0
        sparse[a] = 1.0
        try:
            mujoco.mj_fullM(model, data, dense)  # MuJoCo >= 4: reads data.M
        except TypeError:
            mujoco.mj_fullM(model, dense, sparse)  # older signature (dst, M)
        i, j = np.nonzero(np.tril(dense))
        if len(i) != 1:
            raise ValueError(f"sparse inertia address {a} maps to {len(i)} lower-triangle entries, expected 1")
        rows.append(int(i[0]))
        cols.append(int(j[0]))
    return qM_addresses_from_pairs(np.array(rows), np.array(cols), dof_adr)


def qM_addresses_from_pairs(rows: np.ndarray, cols: np.ndarray, dof_adr: np.ndarray) -> np.ndarray:
    """(4, 3, 3) sparse-inertia addresses of the leg blocks, given each stored entry's (row, col).

    For a sparse layout other than the C model's, e.g. MuJoCo Warp's sparse ``qM`` (its model's
    ``qM_fullm_i``, ``qM_fullm_j`` give the row and column of each element; their order follows
    MuJoCo Warp's version, not necessarily C MuJoCo 4's CSR order).

    Args:
        rows, cols: (nM,) dof row and column (row >= col) of each stored element.
        dof_adr: (4, 3) dof addresses of the leg joints (:attr:`LegChainParams.dof_adr`).
    """
    rows, cols = np.asarray(rows), np.asarray(cols)
    lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
    where = {(int(r), int(c)): a for a, (r, c) in enumerate(zip(hi, lo))}
    r = np.maximum(dof_adr[:, :, None], dof_adr[:, None, :])
    c = np.minimum(dof_adr[:, :, None], dof_adr[:, None, :])
    try:
        return np.vectorize(lambda i, j: where[(int(i), int(j))])(r, c).astype(np.int64)
    except KeyError as err:
        raise ValueError(f"leg block entry {err.args[0]} of the mass matrix is not stored in the sparse inertia "
                         "(legs must be serial chains)") from None
