"""Student: output layout and scaling, first-action decoding, export round trip, and learning a
synthetic linear expert whose encoded horizon is known in closed form."""

from __future__ import annotations

import math

import pytest
import torch

from dls_quadruped.learning.distill_config import load_distill_config
from dls_quadruped.learning.distill_trainer import DistillTrainer
from dls_quadruped.learning.student import (
    Student,
    encode_labels,
    export_student,
    first_action_index,
    label_scale,
    load_student,
    metadata,
)
from dls_quadruped.mpc.config import EncodingConfig
from dls_quadruped.mpc.encodings import decode, encode, encoded_dim

ALL = [(p, F, H) for p in ("discrete", "spline", "first") for F in ("discrete", "spline", "first") for H in (5, 10, 15)]


@pytest.mark.parametrize("p,F,H", ALL)
def test_student_output_is_the_encoded_dimension_and_first_action_decodes(p, F, H):
    cfg = EncodingConfig(p, F, H)
    torch.manual_seed(0)
    student = Student(7, cfg, [16])
    obs = torch.randn(3, 7)
    out = student(obs)
    assert out.shape == (3, encoded_dim(cfg))  # Table 13 dims are checked in tests/mpc/test_encodings.py
    torch.testing.assert_close(student.first_action(obs), decode(out, cfg)[:, 0, :])


def test_curvature_parameters_are_learnt_divided_by_ten():
    cfg = EncodingConfig("first", "spline", 10)  # 8 + 8 + 48 = 64
    scale = label_scale(cfg)
    assert scale.shape == (64,)
    f_block = scale[16:].view(12, 4)  # per F scalar [theta_-1, theta_0, theta_1, theta_2]
    assert torch.equal(f_block[:, [0, 3]], torch.full((12, 2), 0.1))
    assert torch.equal(f_block[:, [1, 2]], torch.ones(12, 2))
    assert torch.equal(scale[:16], torch.ones(16))
    acts = torch.randn(5, 10, 28)
    torch.testing.assert_close(encode_labels(acts, cfg), encode(acts, cfg) * scale)
    student = Student(4, cfg, [8])
    obs = torch.randn(2, 4)
    torch.testing.assert_close(student(obs), student.net(obs) / scale)  # x10 on the way out
    assert label_scale(EncodingConfig("discrete", "first", 5)).eq(1).all()


def test_first_action_index_of_a_spline_is_theta_0():
    cfg = EncodingConfig("spline", "spline", 5)  # p: 8 scalars x 4 from index 8; F: 12 x 4 from 40
    idx = first_action_index(cfg)
    assert idx[:8].tolist() == list(range(8))
    assert idx[8:10].tolist() == [9, 13]
    assert idx[16].item() == 41


def test_export_round_trip(tmp_path, save_policy):
    cfg = EncodingConfig("first", "spline", 10)
    torch.manual_seed(1)
    student = Student(259, cfg, [32, 16])
    student.obs_normalizer.update(torch.randn(100, 259) * 3 + 1)  # non-trivial normaliser state
    student.eval()
    meta = metadata(cfg, 0.02, 259, {"expert": {"path": "x.pt"}})
    path = export_student(student, meta, tmp_path / "student.pt")
    loaded, meta_back = load_student(path)
    obs = torch.randn(6, 259)
    torch.testing.assert_close(loaded(obs), student(obs))
    torch.testing.assert_close(loaded.first_action(obs), student.first_action(obs))
    assert meta_back == meta and meta_back["encoding"] == {"p": "first", "F": "spline", "horizon": 10, "dt": 0.02,
                                                           "constrained_fit": True}
    assert meta_back["output_dim"] == 64 and (tmp_path / "student.json").is_file()
    with pytest.raises(ValueError, match="not a distilled student"):
        load_student(save_policy(torch.nn.Linear(2, 2), 2, tmp_path / "plain.pt2"))


def rotation(dim: int, angle: float) -> torch.Tensor:
    R = torch.eye(dim)
    for i in range(0, dim - 1, 2):
        c, s = math.cos(angle * (i + 1)), math.sin(angle * (i + 1))
        R[i:i + 2, i:i + 2] = torch.tensor([[c, -s], [s, c]])
    return R


@pytest.fixture
def one_thread():
    """Small matrices: one intra-op thread is several times faster on a shared 2-core machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def test_student_learns_a_linear_expert_to_near_zero_mse(tmp_path, one_thread, linear_env):
    """Expert a = K s on s_{t+1} = A s + B a with A + B K = R (a rotation): its horizon at s_t is
    K R^{jk} s_t, j = 0..H-1, so every label is a known linear function of s_t."""
    gen = torch.Generator().manual_seed(0)
    dim = 4
    K = 0.5 * torch.randn(28, dim, generator=gen)
    B = 0.1 * torch.randn(dim, 28, generator=gen)
    R = rotation(dim, 0.15)
    env = linear_env(64, R - B @ K, B)
    cfg = load_distill_config(overrides={
        "algorithm": "naive", "encoding": {"p": "first", "F": "spline", "horizon": 5, "dt": 0.04},
        "train": {"epochs": 6, "datapoints_per_epoch": 1000, "dataset_cap": 6000, "batch_size": 64, "passes": 3,
                  "lr_decay": 0.9},
        "evaluate": {"test_datapoints": 500, "test_episodes": 4}, "student": {"hidden_dims": [64, 64]}})
    trainer = DistillTrainer(cfg, env, lambda s: s @ K.T, tmp_path, [64, 64], "elu", printer=lambda *a, **k: None)
    trainer.open_datasets(resume=False)
    trainer.collect_test_set()
    enc = cfg.encoding.to_encoding()
    obs, labels = trainer.test_set.ordered()
    horizon = torch.stack([obs @ torch.linalg.matrix_power(R, 2 * j).T @ K.T for j in range(5)], dim=1)
    torch.testing.assert_close(labels, encode_labels(horizon, enc), rtol=1e-4, atol=1e-4)  # labels by hand
    for _ in range(cfg.train.epochs):
        trainer._collect_epoch()
        trainer.train_pass()
        trainer.epoch += 1
    with torch.no_grad():
        mse = torch.nn.functional.mse_loss(trainer.student.net(obs), labels).item()
    assert mse < 2e-3 * labels.var().item(), (mse, labels.var().item())  # an untrained net: ~1x
