"""Exported networks on disk: programs written and read back, TorchScript read, files told apart by content."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch

from dls_quadruped.learning.export import main as export_main
from dls_quadruped.learning.export import typical_observations
from dls_quadruped.learning.policy_file import ExportedModule, file_kind, load_module

POLICIES = Path(__file__).resolve().parents[2] / "docs" / "policies"


def test_program_round_trip_at_any_batch_size(tmp_path, save_policy):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(5, 8), torch.nn.ELU(), torch.nn.Linear(8, 3))
    path = save_policy(net, 5, tmp_path / "net.pt2", extra_files={"meta.json": '{"a": 1}'})
    assert [p.name for p in tmp_path.iterdir()] == ["net.pt2"]  # no temporary file left
    extra = {"meta.json": "", "absent.json": ""}
    loaded = load_module(path, extra_files=extra)
    assert isinstance(loaded, ExportedModule) and loaded.input_size == 5 and not loaded.training
    assert extra == {"meta.json": '{"a": 1}', "absent.json": ""}
    assert loaded.state_dict().keys() == net.state_dict().keys()
    for batch in (1, 2, 33):  # the example had 2 rows; 1 must not be a special case
        x = torch.randn(batch, 5)
        with torch.no_grad():
            torch.testing.assert_close(loaded(x), net(x), rtol=0, atol=0)
    with pytest.raises(RuntimeError, match=r"takes \(batch, 5\) observations, got \(4, 6\)"):
        loaded(torch.zeros(4, 6))


def test_files_are_told_apart_by_their_records(tmp_path, save_policy):
    renamed = save_policy(torch.nn.Linear(2, 2), 2, tmp_path / "policy.pt")  # a program under a .pt name
    (tmp_path / "junk.pt").write_bytes(b"junk")
    assert file_kind(renamed) == "program" and isinstance(load_module(renamed), ExportedModule)
    assert file_kind(POLICIES / "base_actor.pt") == "torchscript"
    assert file_kind(POLICIES / "base_student_first_spline_h10.pt") == "torchscript"
    assert file_kind(POLICIES / "base_networks.pt") == "checkpoint"
    assert file_kind(tmp_path / "junk.pt") is None and file_kind(tmp_path / "none.pt") is None
    with pytest.raises(ValueError, match="a training checkpoint, not an exported network"):
        load_module(POLICIES / "base_networks.pt")


def test_committed_torchscript_actor_loads_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        actor = load_module(POLICIES / "base_actor.pt")
    assert not actor.training and actor(torch.zeros(3, 259)).shape == (3, 28)


def test_committed_actor_reexported_as_a_program_acts_as_the_torchscript(tmp_path):
    """``python -m dls_quadruped.learning.export docs/policies/base_actor.pt OUT.pt2``: the same actions
    (the same float32 operations, one graph traced from rsl-rl's module, the other scripted)."""
    out = export_main([str(POLICIES / "base_actor.pt"), str(tmp_path / "base_actor.pt2"), "--task", "base"])
    program, torchscript = load_module(out), load_module(POLICIES / "base_actor.pt")
    assert isinstance(program, ExportedModule) and program.input_size == 259
    for key, value in torchscript.state_dict().items():
        assert torch.equal(program.state_dict()[key], value), key
    obs = typical_observations(torchscript, 64)
    with torch.no_grad():
        assert (program(obs) - torchscript(obs)).abs().max() <= 1e-6
