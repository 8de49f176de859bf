"""A short training run saves atomic checkpoints, resumes, and exports a policy equal to the checkpoint."""

from __future__ import annotations

from pathlib import Path

import onnx
import onnxruntime as ort  # dev extra: the numeric ONNX check is not optional
import pytest
import torch
from tensordict import TensorDict

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning import train
from dls_quadruped.learning.export import ONNX_ATOL, onnx_error, typical_observations
from dls_quadruped.learning.policy_file import ExportedModule, load_module
from dls_quadruped.learning.runner import (
    AtomicOnPolicyRunner,
    latest_checkpoint,
    runner_config,
)


def test_train_resume_export(tmp_path):
    common = ["--task", "base", "--num-envs", "8", "--num-workers", "0", "--log-root", str(tmp_path),
              "--save-interval", "1"]
    run_dir = train.main([*common, "--iterations", "2"])
    assert (run_dir / "task.yaml").is_file() and (run_dir / "agent.yaml").is_file()
    assert latest_checkpoint(run_dir).name == "model_1.pt"
    assert not list(run_dir.glob("*.tmp"))  # atomic writes leave no partial file
    first = torch.load(run_dir / "model_1.pt", weights_only=False)
    resumed = train.main([*common, "--iterations", "2", "--resume"])
    assert resumed == run_dir
    ckpt = latest_checkpoint(run_dir)
    assert ckpt.name == "model_3.pt"
    last = torch.load(ckpt, weights_only=False)
    assert last["iter"] == 3
    # training continued from the checkpoint: weights moved on from iteration 1
    key = next(k for k in first["actor_state_dict"] if "weight" in k)
    assert not torch.equal(first["actor_state_dict"][key], last["actor_state_dict"][key])

    # exported program and ONNX policies == the checkpoint's deterministic actor, at any batch size
    task = load_task("base", overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=8, verbose=False)
    try:
        runner = AtomicOnPolicyRunner(env, runner_config(task.data["agent"]), log_dir=None)
        runner.load(str(ckpt))
        policy = runner.get_inference_policy()
        obs = env.get_observations()
        for _ in range(3):
            obs, *_ = env.step(torch.randn(8, 28))
        program = load_module(run_dir / "exported" / "policy.pt2")
        assert isinstance(program, ExportedModule)
        onnx_path = run_dir / "exported" / "policy.onnx"
        assert not list(onnx_path.parent.glob("*.data"))  # weights embedded: the .onnx alone is the policy
        for batch, x in (("env", obs["policy"]), ("1", typical_observations(program, 1)),
                         ("64", typical_observations(program, 64))):
            with torch.no_grad():
                expected = policy(TensorDict({"policy": x}, batch_size=[x.shape[0]]))
                got_program = program(x)
            sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
            got_onnx = torch.from_numpy(sess.run(None, {"obs": x.numpy()})[0])
            assert expected.shape == (x.shape[0], 28), batch
            assert (got_program - expected).abs().max() <= 1e-5, batch
            assert (got_onnx - expected).abs().max() <= 1e-5, batch
        model = onnx.load(str(onnx_path))
        onnx.checker.check_model(model)
        dims = model.graph.input[0].type.tensor_type.shape.dim
        assert dims[0].dim_param and dims[1].dim_value == obs["policy"].shape[1]  # batch axis is free
    finally:
        env.close()


@pytest.mark.parametrize("task", ["base", "rough", "speed", "climb"])
def test_committed_actor_onnx_matches_its_torchscript(task):
    """docs/policies/<task>_actor.onnx was exported with <task>_actor.pt (``python -m
    dls_quadruped.learning.export``); both give the same actions for 1 and for 64 observations."""
    root = Path(__file__).resolve().parents[2] / "docs" / "policies"
    jit = load_module(root / f"{task}_actor.pt")
    for batch in (1, 64):
        assert onnx_error(root / f"{task}_actor.onnx", jit, batch) <= ONNX_ATOL, batch
    assert ONNX_ATOL == 1e-5
