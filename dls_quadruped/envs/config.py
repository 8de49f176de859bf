"""Task YAML loading: explicit inheritance, deep merge, provenance and validation helpers.

A task file may start with ``inherit: <file>`` (a path relative to the task file, or a list of
them, applied left to right). The parent is loaded first (recursively), then the child is
deep-merged onto it: dicts merge key by key, every other value (lists, scalars) replaces the
parent's, and a value of ``null`` deletes the key (e.g. a task that drops a reward term writes
``rewards: {flat_orientation: null}``). Every leaf remembers the file that set it, so a
validation error names the file and the dotted key, e.g.
``tasks/climb.yaml: rewards.track_lin_vel.params.sigm: unknown parameter; allowed: [...]``.
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any

import yaml

TASKS_DIR = Path(__file__).resolve().parents[2] / "tasks"
TOP_LEVEL_KEYS = ("env", "terrain", "scene", "observations", "actions", "commands", "rewards", "terminations",
                  "events", "curriculum", "agent")


class ConfigError(ValueError):
    """A task configuration error; the message names the file, the key and the allowed values."""


@dataclasses.dataclass
class TaskConfig:
    """A resolved task: merged data plus where each key came from.

    Attributes:
        name: task name (file stem).
        path: the task file.
        data: the merged configuration (plain dicts/lists/scalars).
        sources: dotted key -> file that set it (leaves and sections).
    """

    name: str
    path: Path
    data: dict
    sources: dict[str, str]

    def source_of(self, key: str) -> str:
        """File that set ``key`` (or its closest parent section)."""
        parts = key.split(".")
        for n in range(len(parts), 0, -1):
            src = self.sources.get(".".join(parts[:n]))
            if src is not None:
                return src
        return str(self.path)

    def error(self, key: str, message: str) -> ConfigError:
        """A ConfigError naming the source file and the dotted key."""
        return ConfigError(f"{self.source_of(key)}: {key}: {message}")

    def section(self, name: str) -> dict:
        value = self.data.get(name) or {}
        if not isinstance(value, dict):
            raise self.error(name, f"must be a mapping, got {type(value).__name__}")
        return value


def _record(sources: dict[str, str], value: Any, prefix: str, src: str) -> None:
    sources[prefix] = src
    if isinstance(value, dict):
        for k, v in value.items():
            _record(sources, v, f"{prefix}.{k}", src)


def _merge(base: dict, child: dict, sources: dict[str, str], src: str, prefix: str = "") -> dict:
    """Deep-merge ``child`` onto ``base`` (in place), recording provenance; ``None`` deletes."""
    for key, value in child.items():
        path = f"{prefix}{key}"
        if value is None:
            base.pop(key, None)
            for k in [k for k in sources if k == path or k.startswith(path + ".")]:
                del sources[k]
        elif isinstance(value, dict) and isinstance(base.get(key), dict):
            sources[path] = src
            _merge(base[key], value, sources, src, path + ".")
        else:
            base[key] = copy.deepcopy(value)
            for k in [k for k in sources if k.startswith(path + ".")]:
                del sources[k]
            _record(sources, value, path, src)
    return base


def _load_file(path: Path, chain: tuple[Path, ...]) -> tuple[dict, dict[str, str]]:
    if path in chain:
        raise ConfigError(f"{path}: inherit: cycle {' -> '.join(str(p) for p in (*chain, path))}")
    if not path.is_file():
        where = f"{chain[-1]}: inherit: " if chain else ""
        raise ConfigError(f"{where}task file {path} not found; available: {available_tasks()}")
    with open(path) as fh:
        raw = yaml.safe_load(fh) or {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: top level must be a mapping")
    parents = raw.pop("inherit", None) or []
    parents = [parents] if isinstance(parents, str) else parents
    data: dict = {}
    sources: dict[str, str] = {}
    for parent in parents:
        p_data, p_sources = _load_file((path.parent / parent).resolve(), (*chain, path))
        _merge(data, p_data, sources, "")
        sources.update(p_sources)
    unknown = sorted(set(raw) - set(TOP_LEVEL_KEYS))
    if unknown:
        raise ConfigError(f"{path}: unknown top-level keys {unknown}; allowed: {['inherit', *TOP_LEVEL_KEYS]}")
    _merge(data, raw, sources, str(path))
    return data, sources


def available_tasks(tasks_dir: Path = TASKS_DIR) -> list[str]:
    """Task names (YAML files in ``tasks/`` not starting with '_')."""
    return sorted(p.stem for p in tasks_dir.glob("*.yaml") if not p.name.startswith("_"))


def load_task(task: str | Path, overrides: dict | None = None) -> TaskConfig:
    """Load a task by name (``tasks/<name>.yaml``) or path, resolving ``inherit`` chains.

    Args:
        task: task name or YAML path.
        overrides: optional dict deep-merged last (e.g. from the command line), recorded as "<override>".
    """
    path = Path(task)
    if path.suffix not in (".yaml", ".yml"):
        path = TASKS_DIR / f"{task}.yaml"
        if not path.is_file():
            raise ConfigError(f"unknown task {task!r}; available: {available_tasks()}")
    path = path.resolve()
    data, sources = _load_file(path, ())
    if overrides:
        _merge(data, overrides, sources, "<override>")
    return TaskConfig(path.stem, path, data, sources)


def dataclass_from_dict(cls: type, values: dict, task: TaskConfig, key: str):
    """Build a (frozen) dataclass from a YAML mapping; lists become tuples; unknown keys fail."""
    allowed = [f.name for f in dataclasses.fields(cls) if not f.name.startswith("_")]
    if not isinstance(values, dict):
        raise task.error(key, f"must be a mapping with keys from {allowed}")
    unknown = sorted(set(values) - set(allowed))
    if unknown:
        raise task.error(f"{key}.{unknown[0]}", f"unknown key; allowed: {allowed}")

    def tup(v):
        return tuple(tup(x) for x in v) if isinstance(v, list) else v

    try:
        return cls(**{k: tup(v) for k, v in values.items()})
    except (TypeError, ValueError) as err:
        raise task.error(key, str(err)) from err


def save_resolved(task: TaskConfig, path: Path) -> None:
    """Write the resolved (merged) configuration next to a run's results."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        fh.write(f"# resolved task '{task.name}' from {task.path}\n")
        yaml.safe_dump(task.data, fh, sort_keys=False)
