"""A short training run saves atomic checkpoints, resumes, and exports a policy equal to the checkpoint."""

from __future__ import annotations

import pytest
import torch

from dls_quadruped.envs.config import load_task
from dls_quadruped.envs.env import LocomotionEnv
from dls_quadruped.learning import train
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

    # exported TorchScript policy == the checkpoint's deterministic actor
    task = load_task("base", overrides={"scene": {"num_workers": 0}})
    env = LocomotionEnv(task, num_envs=8, verbose=False)
    try:
        runner = AtomicOnPolicyRunner(env, runner_config(task.data["agent"]), log_dir=None)
        runner.load(str(ckpt))
        policy = runner.get_inference_policy()
        obs = env.get_observations()
        for _ in range(3):
            obs, *_ = env.step(torch.randn(8, 28))
        with torch.no_grad():
            expected = policy(obs)
            jit = torch.jit.load(str(run_dir / "exported" / "policy.pt"))
            got = jit(obs["policy"])
        assert expected.shape == (8, 28)
        assert torch.allclose(got, expected, atol=1e-5)
        # ONNX: the graph must be valid; numeric equality needs onnxruntime (not a dependency here)
        onnx = pytest.importorskip("onnx")
        model = onnx.load(str(run_dir / "exported" / "policy.onnx"))
        onnx.checker.check_model(model)
        assert model.graph.input[0].type.tensor_type.shape.dim[1].dim_value == obs["policy"].shape[1]
        try:
            import onnxruntime as ort
        except ImportError:
            return
        sess = ort.InferenceSession(str(run_dir / "exported" / "policy.onnx"))
        out = sess.run(None, {sess.get_inputs()[0].name: obs["policy"].numpy()})[0]
        assert torch.allclose(torch.from_numpy(out), expected, atol=1e-4)
    finally:
        env.close()
