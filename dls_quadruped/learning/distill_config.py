"""Distillation settings (thesis 5.2, Table 7): the YAML file ``tasks/agents/distill.yaml``.

The file has five sections, each a frozen dataclass checked when it is loaded (unknown keys, wrong
types, values out of range fail naming the file and the dotted key, as task files do):

    task: base                          # env task the expert acts in (also the SP reward)
    expert: docs/policies/base_actor.pt # TorchScript actor, 259 observations -> 28 raw actions
    algorithm: dagger                   # naive | dagger
    encoding: {p: first, F: spline, horizon: 10, dt: 0.02, constrained_fit: true}
    selector: {kind: exponential, alpha: 0.6}
    train: {epochs: 30, datapoints_per_epoch: 80000, dataset_cap: 800000, batch_size: 64, ...}
    collect: {num_envs: 128}
    evaluate: {test_datapoints: 50000, sp_episodes: 128, ...}
    student: {hidden_dims: null, activation: null}   # null: the expert actor's (task agent.actor)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from dls_quadruped.envs.config import (
    ConfigError,
    TaskConfig,
    _record,
)
from dls_quadruped.envs.value_checks import dataclass_from_dict
from dls_quadruped.mpc.config import ENCODING_KINDS, EncodingConfig

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "tasks" / "agents" / "distill.yaml"
ALGORITHMS = ("naive", "dagger")
SELECTORS = ("exponential", "indicator")
NAIVE_SCHEDULES = ("full", "dagger_steps")
TOP_KEYS = ("task", "expert", "algorithm", "encoding", "selector", "train", "collect", "evaluate", "student")
DT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class EncodingSection:
    """p, F: encodings ("discrete" | "spline" | "first"); horizon: H >= 1 (>= 4 with a spline);
    dt [s]: spacing of the H actions, a multiple of the env step (0.02 s); constrained_fit: A.3."""

    p: str = "first"
    F: str = "spline"
    horizon: int = field(default=10, metadata={"min": 1})
    dt: float = field(default=0.02, metadata={"gt": 0.0})
    constrained_fit: bool = True

    def __post_init__(self) -> None:
        for name in ("p", "F"):
            if getattr(self, name) not in ENCODING_KINDS:
                raise ValueError(f"unknown encoding {name}={getattr(self, name)!r}; allowed: {list(ENCODING_KINDS)}")
        self.to_encoding()  # H >= 4 with a spline

    def to_encoding(self) -> EncodingConfig:
        return EncodingConfig(p=self.p, F=self.F, horizon=self.horizon, constrained_fit=self.constrained_fit)

    def stride(self, step_dt: float) -> int:
        """Env steps between two actions of the horizon (dt / step_dt, an integer >= 1).

        Raises:
            ValueError: dt is not a positive multiple of the env step.
        """
        k = self.dt / step_dt
        if round(k) < 1 or abs(k - round(k)) > DT_TOLERANCE * max(1.0, k):
            raise ValueError(f"encoding.dt = {self.dt} s is not a multiple of the env step {step_dt} s; "
                             f"allowed: {step_dt:g}, {2 * step_dt:g}, {3 * step_dt:g}, ...")
        return round(k)


@dataclass(frozen=True)
class SelectorSection:
    """beta(i) of DAgger (eq. 5.2.1): ``exponential`` alpha^i (0 < alpha < 1) or ``indicator``
    (1 at epoch 0, else 0). Naive imitation ignores it (the expert always drives)."""

    kind: str = "exponential"
    alpha: float = 0.6

    def __post_init__(self) -> None:
        if self.kind not in SELECTORS:
            raise ValueError(f"unknown selector kind {self.kind!r}; allowed: {list(SELECTORS)}")
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")


@dataclass(frozen=True)
class TrainSection:
    """Table 7: epochs, datapoints collected per epoch, dataset cap (FIFO), Adadelta learning rate
    decayed by ``lr_decay`` per epoch, mini-batch size; ``passes``: passes over the dataset per
    epoch; ``seed``: torch seed of the student and the collection; ``naive_schedule`` (naive only):
    ``full`` trains every epoch on the whole dataset (Algorithm 3), ``dagger_steps`` trains epoch i
    on a random min(size, (i + 1) datapoints_per_epoch) of it, the gradient steps DAgger makes."""

    epochs: int = field(default=30, metadata={"min": 1})
    datapoints_per_epoch: int = field(default=80_000, metadata={"min": 1})
    dataset_cap: int = field(default=800_000, metadata={"min": 1})
    batch_size: int = field(default=64, metadata={"min": 1})
    learning_rate: float = field(default=1.0, metadata={"gt": 0.0})
    lr_decay: float = field(default=0.7, metadata={"gt": 0.0})
    passes: int = field(default=1, metadata={"min": 1})
    seed: int = 0
    naive_schedule: str = "full"

    def __post_init__(self) -> None:
        if self.naive_schedule not in NAIVE_SCHEDULES:
            raise ValueError(f"unknown naive_schedule {self.naive_schedule!r}; allowed: {list(NAIVE_SCHEDULES)}")


@dataclass(frozen=True)
class CollectSection:
    """num_envs: robots stepped together; num_workers: simulator processes (null: the task's)."""

    num_envs: int = field(default=128, metadata={"min": 1})
    num_workers: int | None = None


@dataclass(frozen=True)
class EvaluateSection:
    """test_datapoints: held-out expert datapoints, windows cut from ``test_episodes`` whole
    episodes the expert plays (schedule seed ``test_seed``, ``learning.distill_test_set``); sp_episodes:
    15 s episodes per SP evaluation (rounded up to whole batches of num_envs, seeds ``sp_seed`` +
    batch); sp_every: SP every k epochs (0: only after the last epoch)."""

    test_datapoints: int = field(default=50_000, metadata={"min": 1})
    test_episodes: int = field(default=128, metadata={"min": 1})
    test_seed: int = 1000
    sp_episodes: int = field(default=128, metadata={"min": 1})
    sp_seed: int = 2000
    sp_every: int = field(default=1, metadata={"min": 0})


@dataclass(frozen=True)
class StudentSection:
    """hidden_dims, activation: null takes the expert actor's (task ``agent.actor``)."""

    hidden_dims: tuple[int, ...] | None = None
    activation: str | None = None


@dataclass(frozen=True)
class DistillConfig:
    task: str
    expert: str
    algorithm: str
    encoding: EncodingSection
    selector: SelectorSection
    train: TrainSection
    collect: CollectSection
    evaluate: EvaluateSection
    student: StudentSection
    path: str = "<defaults>"

    def to_dict(self) -> dict:
        data = dataclasses.asdict(self)
        data.pop("path")
        return _lists(data)


def _lists(value):
    if isinstance(value, dict):
        return {k: _lists(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_lists(v) for v in value]
    return value


SECTIONS = {"encoding": EncodingSection, "selector": SelectorSection, "train": TrainSection,
            "collect": CollectSection, "evaluate": EvaluateSection, "student": StudentSection}


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_distill_config(path: str | Path | None = None, overrides: dict | None = None) -> DistillConfig:
    """Read and check a distillation YAML file (default ``tasks/agents/distill.yaml``).

    Args:
        overrides: nested dict merged on top (command-line values), recorded as "<override>".

    Raises:
        ConfigError: naming the file (or <override>), the dotted key and what is allowed.
    """
    path = Path(path or DEFAULT_CONFIG)
    if not path.is_file():
        raise ConfigError(f"distillation config {path} not found")
    try:
        raw = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(err).split())}") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: top level must be a mapping with keys {list(TOP_KEYS)}")
    sources: dict[str, str] = {}
    for k, v in raw.items():
        _record(sources, v, k, str(path))
    data = _merge(raw, overrides or {})
    for k, v in (overrides or {}).items():
        _record(sources, v, k, "<override>")
    cfg = TaskConfig(path.stem, path, data, sources)
    unknown = sorted(set(data) - set(TOP_KEYS))
    if unknown:
        raise cfg.error(unknown[0], f"unknown key; allowed: {list(TOP_KEYS)}")
    for key in ("task", "expert", "algorithm"):
        if not isinstance(data.get(key), str):
            raise cfg.error(key, f"must be a string, got {data.get(key)!r}")
    if data["algorithm"] not in ALGORITHMS:
        raise cfg.error("algorithm", f"unknown algorithm {data['algorithm']!r}; allowed: {list(ALGORITHMS)}")
    sections = {name: dataclass_from_dict(cls, data.get(name) or {}, cfg, name) for name, cls in SECTIONS.items()}
    if sections["train"].dataset_cap < sections["train"].batch_size:
        raise cfg.error("train.dataset_cap", f"must be >= train.batch_size ({sections['train'].batch_size})")
    if not math.isfinite(sections["encoding"].dt):
        raise cfg.error("encoding.dt", "must be finite")
    return DistillConfig(task=data["task"], expert=data["expert"], algorithm=data["algorithm"], path=str(path),
                         **sections)
