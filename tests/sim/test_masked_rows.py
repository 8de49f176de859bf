"""Backends take a (N,) bool mask wherever they take row ids (``sim/interface.py``): the env resets and pushes by
masks, with values for every robot, so that a GPU step has static shapes. A mask must do exactly what the ids of its
True rows do, whatever the other rows' values (NaN included)."""

from __future__ import annotations

import mujoco
import pytest
import torch

from dls_quadruped.core.state import RobotState
from dls_quadruped.robots.aliengo import constants as C
from dls_quadruped.sim.interface import SimConfig, home_state
from dls_quadruped.sim.registry import make_backend

N = 4


def _full(rows: list[int], values: torch.Tensor) -> torch.Tensor:
    """(N, ...) with ``values`` in ``rows`` and NaN elsewhere (rows a mask must ignore)."""
    out = torch.full((N, *values.shape[1:]), float("nan"), dtype=values.dtype)
    out[rows] = values
    return out


def _mask(rows: list[int]) -> torch.Tensor:
    m = torch.zeros(N, dtype=torch.bool)
    m[rows] = True
    return m


def _drive(sim, by_mask: bool) -> list[torch.Tensor]:
    """Resets, a push, a wrench and model fields on some rows, steps in between; every published state field after."""
    def rows(ids: list[int], *values: torch.Tensor):
        return (_mask(ids), *(_full(ids, v) for v in values)) if by_mask else (torch.tensor(ids), *values)

    home = home_state(N, 3, 0.1, yaw=0.4)
    sim.reset(torch.arange(N), **home)
    sim.step(3)
    ids = [1, 3]
    pos = home["base_pos_w"][ids] + torch.tensor([0.1, -0.2, 0.05], dtype=torch.float64)
    sim.reset(*rows(ids, pos, home["base_quat_w"][ids], home["joint_pos"][ids] * 1.05))
    sim.step(2)
    sim.set_base_velocity(*rows([0], torch.tensor([[0.4, -0.3, 0.1]])))
    sim.set_external_wrench(*rows([2], torch.tensor([[5.0, 0.0, -3.0]]), torch.tensor([[0.0, 0.3, 0.0]])))
    mass = torch.as_tensor(sim.model.body_mass, dtype=torch.float64)[None] * 1.1
    sim.set_model_field("body_mass", *rows([3], mass))
    feet = [mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in C.FOOT_GEOM_NAMES]
    friction = torch.as_tensor(sim.model.geom_friction[feet], dtype=torch.float64)[None] * 0.7
    ids_or_mask, values = rows([0], friction)
    sim.set_model_field("geom_friction", ids_or_mask, values, index=feet)
    state = sim.step(4)
    return [getattr(state, f).clone() for f in RobotState.__dataclass_fields__]


@pytest.mark.parametrize("backend", ["cpu", "warp-cpu"])
def test_a_mask_does_what_the_ids_of_its_rows_do(backend):
    if backend == "warp-cpu":
        pytest.importorskip("mujoco_warp", reason="MuJoCo Warp is not installed (optional [gpu] extra)")
    model = mujoco.MjModel.from_xml_path(str(C.SCENE_PATH))
    cfg = SimConfig(num_workers=0, nthread=1)
    by_ids, by_mask = make_backend(backend, model, N, cfg), make_backend(backend, model, N, cfg)
    try:
        a, b = _drive(by_ids, False), _drive(by_mask, True)
        if backend == "warp-cpu":
            by_mask.check_inputs()  # the NaN rows the mask left out were not flagged
            by_mask.set_base_velocity(_mask([1]), torch.full((N, 3), float("nan")))  # in a masked row: flagged
            with pytest.raises(ValueError, match="non-finite lin_vel_w"):
                by_mask.check_inputs()
    finally:
        by_ids.close()
        by_mask.close()
    for name, x, y in zip(RobotState.__dataclass_fields__, a, b, strict=True):
        assert torch.equal(x, y), name
