"""A reset robot starts from the standing references, not from the last ones of its previous episode."""

from __future__ import annotations

import mujoco
import torch

from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.cpu_backend import SimConfig, VecSim


def test_reset_restores_standing_references_of_the_reset_robots_only():
    with VecSim(mujoco.MjModel.from_xml_path(str(C.SCENE_PATH)), 2, SimConfig(num_workers=0)) as sim:
        weight = sim.total_weight()
        state = sim.state
        p_td_w = state.foot_pos_w.double().clone()
        F_w = torch.zeros(2, 4, 3, dtype=torch.float64)
        F_w[..., 2] = weight / 2
        sim.set_references(torch.full((2, 4), 2.0, dtype=torch.float64), torch.full((2, 4), 0.3, dtype=torch.float64),
                           p_td_w, F_w)
        sim.step(4)
        state = sim.reset(torch.tensor([0]), state.base_pos_w[:1].double(), state.base_quat_w[:1].double(),
                          torch.as_tensor(C.NOMINAL_JOINT_POS, dtype=torch.float64)[None])
        c = sim.buf.command
        assert c["duty"][0].tolist() == [1.0] * 4 and c["freq"][0].tolist() == [0.0] * 4
        assert torch.allclose(c["F_w"][0, :, 2], torch.full((4,), weight / 4, dtype=torch.float64))
        assert (c["F_w"][0, :, :2] == 0).all()
        # trot phases (0, 0.5, 0.5, 0) < d = 1: all four legs in stance (with the old d = 0.3 only FL and RR were)
        assert state.contact_cmd[0].tolist() == [1.0] * 4
        assert c["duty"][1].tolist() == [0.3] * 4  # the robot that was not reset keeps its references
