"""Export a trained actor: a ``torch.export`` program (``learning/policy_file.py``) and ONNX, both with a free
batch size and the observation normaliser inside."""

from __future__ import annotations

import warnings
from pathlib import Path

import torch
from rsl_rl.runners import OnPolicyRunner

from dls_quadruped.learning.policy_file import save_program


def export_policy(runner: OnPolicyRunner, out_dir: Path) -> dict[str, Path | str]:
    """Export the deterministic actor (with its observation normaliser) as a ``torch.export`` program
    ``out_dir/policy.pt2`` and, if possible, as ONNX ``out_dir/policy.onnx``.

    Returns:
        {"program": path, "onnx": path or the reason it was skipped}.
    """
    out_dir = Path(out_dir)
    program = export_actor_program(runner.alg.get_policy(), out_dir / "policy.pt2")
    result: dict[str, Path | str] = {"program": program}
    try:
        runner.export_policy_to_onnx(str(out_dir), "policy.onnx")
        result["onnx"] = out_dir / "policy.onnx"
    except (ImportError, RuntimeError) as err:  # onnx/onnxscript missing or an exporter failure: report it
        result["onnx"] = f"skipped: {type(err).__name__}: {err}"
    return result


def export_actor_program(actor, path: Path) -> Path:
    """Export an rsl-rl ``MLPModel`` actor (normaliser + MLP + mean action) as a ``torch.export`` program
    ``obs (B, obs_dim) -> actions (B, num_actions)`` with a free batch size (``learning/policy_file.py``)."""
    # rsl-rl's inference module of the actor (what its own TorchScript export scripts): plain torch, exportable
    return save_program(actor.as_jit(), actor.obs_dim, path)


def export_actor_onnx(actor, path: Path, verbose: bool = False) -> Path:
    """Export an rsl-rl ``MLPModel`` actor (normaliser + MLP + mean action) to ONNX with a dynamic batch axis.

    Weights are embedded (no ``.data`` file); opset 18, torch's ``torch.export``-based exporter.
    """
    model = actor.as_onnx(verbose=verbose).to("cpu").eval()
    # batch 2, not 1: torch.export turns a size-1 example dimension into a constant
    example = torch.zeros(2, model.input_size)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        # torch's exporter copies the graph through a pytree check that torch itself deprecates: nothing to act on here
        warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated",
                                category=FutureWarning)
        torch.onnx.export(model, (example,), str(path), dynamo=True, external_data=False, opset_version=18,
                          input_names=model.input_names, output_names=model.output_names, verbose=verbose,
                          dynamic_shapes=({0: torch.export.Dim("batch")},))
    return path
