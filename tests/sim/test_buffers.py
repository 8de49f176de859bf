"""``sim/buffers.py``: the shared buffers' layout, their row views, and where the contact sensors lie."""

from __future__ import annotations

import mujoco
import torch

from dls_quadruped.core.state import RobotState
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.buffers import COMMAND_SPECS, STATE_SPECS, SharedBuffers, contact_sensor_layout


def test_buffers_follow_the_specs_and_rows_are_views():
    buf = SharedBuffers.allocate(5, shared=True)
    assert {k: tuple(v.shape) for k, v in buf.state.items()} == {k: (5, *s) for k, s in STATE_SPECS.items()}
    assert {k: tuple(v.shape) for k, v in buf.command.items()} == {k: (5, *s) for k, s in COMMAND_SPECS.items()}
    assert all(v.dtype == torch.float32 and v.is_shared() for v in buf.state.values())
    assert all(v.dtype == torch.float64 and v.is_shared() for v in buf.command.values())
    assert set(STATE_SPECS) <= {f for f in RobotState.__dataclass_fields__}  # named as the state's fields
    rows = buf.rows(2, 4)
    rows.state["phase"][1] = 0.25  # robot 3
    rows.command["F_w"][0, 2, 2] = 80.0  # robot 2, RL, z
    assert buf.state["phase"][3].tolist() == [0.25] * 4 and float(buf.command["F_w"][2, 2, 2]) == 80.0
    assert float(buf.state["phase"].sum()) == 1.0 and float(buf.command["F_w"].sum()) == 80.0
    assert not SharedBuffers.allocate(1, shared=False).state["time"].is_shared()


def test_contact_sensor_layout_covers_the_nine_sensors_without_overlap():
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    layout = contact_sensor_layout(model)
    names = [*(f"{leg}_foot_contact" for leg in C.LEG_NAMES), "trunk_contact",
             *(f"{leg}_thigh_contact" for leg in C.LEG_NAMES)]
    assert list(layout) == names
    covered = sorted(i for s in layout.values() for i in range(s.start, s.stop))
    assert len(covered) == len(set(covered)) and covered[-1] < model.nsensordata
    for name, s in layout.items():
        sensor = model.sensor(name)
        assert (s.start, s.stop - s.start) == (int(sensor.adr[0]), int(sensor.dim[0]))


def test_buffers_are_disjoint_contiguous_views_of_two_blocks():
    buf = SharedBuffers.allocate(3, shared=True)
    for group, dtype in ((buf.state, torch.float32), (buf.command, torch.float64)):
        assert len({v.untyped_storage().data_ptr() for v in group.values()}) == 1  # one block (segment) each
        assert all(v.is_contiguous() for v in group.values())
        for v in group.values():  # each buffer written alone changes only its own elements of the block
            v.fill_(1.0)
            assert sum(float(w.sum()) for w in group.values()) == v.numel()
            v.zero_()
        assert sum(v.numel() for v in group.values()) * dtype.itemsize == group["freq" if dtype == torch.float64
                                                                               else "time"].untyped_storage().nbytes()
