"""Task YAML loading: explicit inheritance, deep merge, provenance, the resolved task written next to a run.

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
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

TASKS_DIR = Path(__file__).resolve().parents[2] / "tasks"
TOP_LEVEL_KEYS = ("env", "terrain", "scene", "observations", "actions", "commands", "rewards", "terminations",
                  "events", "curriculum", "agent")
REQUIRED_SECTIONS = ("env", "agent")
"""Sections a task (not a ``_`` fragment) must have after inheritance: what ``train`` reads without defaults."""


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


_TASK_CHECKS: list[Callable[[TaskConfig], None]] = []


def register_task_check(check: Callable[[TaskConfig], None]) -> None:
    """Run ``check`` on every task ``load_task`` validates (``envs/__init__.py`` registers ``envs/validate.py``)."""
    if check not in _TASK_CHECKS:
        _TASK_CHECKS.append(check)


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


def _top_level_line(text: str, key: str) -> int | None:
    """1-based line of the top-level ``key:`` of a YAML text (None if absent or unreadable)."""
    try:
        node = yaml.compose(text)
    except yaml.YAMLError:
        return None
    if isinstance(node, yaml.MappingNode):
        for key_node, _ in node.value:
            if key_node.value == key:
                return key_node.start_mark.line + 1
    return None


def _yaml_error(path: Path, err: yaml.YAMLError) -> str:
    """One line for a YAML syntax error: file, line and column, YAML's problem, what is expected."""
    mark = getattr(err, "problem_mark", None)
    where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
    problem = getattr(err, "problem", None) or str(err).splitlines()[0]
    if "'\\t'" in problem:
        problem = "found a tab character; YAML indents with spaces only"
    context, context_mark = getattr(err, "context", None), getattr(err, "context_mark", None)
    if context and context_mark is not None and context_mark.line != getattr(mark, "line", None):
        problem += f" ({context} that starts on line {context_mark.line + 1})"
    return (f"{where}: invalid YAML: {problem}; expected `section:` lines with their keys indented by the "
            "same number of spaces, and every [ and { closed")


def _read_mapping(path: Path) -> dict:
    """The top-level mapping of one task file; anything else is a ConfigError naming the file and line."""
    text = path.read_text()
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(_yaml_error(path, err)) from None
    expected = f"expected a mapping of sections from {['inherit', *TOP_LEVEL_KEYS]}"
    if raw is None:
        raise ConfigError(f"{path}: the file is empty (or only comments); {expected}")
    if not isinstance(raw, dict):
        kind = "list" if isinstance(raw, list) else f"single value ({type(raw).__name__} {raw!r:.40})"
        line = yaml.compose(text).start_mark.line + 1
        raise ConfigError(f"{path}:{line}: the top level is a {kind}; {expected}")
    unknown = sorted(str(k) for k in set(raw) - set(TOP_LEVEL_KEYS) - {"inherit"})
    if unknown:
        line = _top_level_line(text, unknown[0])
        raise ConfigError(f"{path}{f':{line}' if line else ''}: unknown top-level keys {unknown}; "
                          f"allowed: {['inherit', *TOP_LEVEL_KEYS]}")
    return raw


def _parents(path: Path, raw: dict) -> list[Path]:
    """The files named by ``inherit`` (relative to ``path``), each checked to exist."""
    parents = raw.pop("inherit", None) or []
    parents = [parents] if isinstance(parents, str) else parents
    line = _top_level_line(path.read_text(), "inherit")
    where = f"{path}{f':{line}' if line else ''}: inherit"
    if not isinstance(parents, list) or not all(isinstance(p, str) for p in parents):
        raise ConfigError(f"{where}: expected a file name or a list of file names, got {parents!r}")
    resolved = [(path.parent / parent).resolve() for parent in parents]
    for name, parent in zip(parents, resolved):
        if not parent.is_file():
            here = sorted(p.name for p in path.parent.glob("*.y*ml"))
            raise ConfigError(f"{where}: {name!r} not found (no file {parent}); files next to it: {here}")
    return resolved


def _load_file(path: Path, chain: tuple[Path, ...]) -> tuple[dict, dict[str, str]]:
    if path in chain:
        raise ConfigError(f"{path}: inherit: cycle {' -> '.join(str(p) for p in (*chain, path))}")
    if not path.is_file():
        raise ConfigError(f"task file {path} not found; available: {available_tasks()}")
    raw = _read_mapping(path)
    data: dict = {}
    sources: dict[str, str] = {}
    for parent in _parents(path, raw):
        p_data, p_sources = _load_file(parent, (*chain, path))
        _merge(data, p_data, sources, "")
        sources.update(p_sources)
    _merge(data, raw, sources, str(path))
    return data, sources


def available_tasks(tasks_dir: Path = TASKS_DIR) -> list[str]:
    """Task names (YAML files in ``tasks/`` not starting with '_')."""
    return sorted(p.stem for p in tasks_dir.glob("*.yaml") if not p.name.startswith("_"))


def task_description(path: Path) -> str:
    """The first sentence of a task file's opening comment ("" if it has none).

    The opening comment is the ``#`` lines before the first other line, up to an indented one (an example
    command); e.g. ``tasks/base.yaml`` -> "Base task (Table 3): +-1 m/s omnidirectional, flat ground, ...".
    """
    words = []
    for line in Path(path).read_text().splitlines():
        if not line.startswith("#") or line.startswith("#  ") or not line[1:].strip():
            break
        words.append(line[1:].strip())
    text = " ".join(words)
    first = re.match(r"(.+?[.!?])(\s|$)", text)
    return (first.group(1) if first else text).rstrip(":")


def merge_overrides(*layers: dict | None) -> dict:
    """One ``load_task`` overrides dict from several, later layers winning: mappings merge key by key,
    any other value (``None`` included, which deletes the key in the task) replaces."""
    out: dict = {}

    def merge(into: dict, layer: dict) -> None:
        for key, value in layer.items():
            if isinstance(value, dict) and isinstance(into.get(key), dict):
                merge(into[key], value)
            else:
                into[key] = copy.deepcopy(value)

    for layer in layers:
        merge(out, layer or {})
    return out


def load_task(task: str | Path, overrides: dict | None = None, validate: bool = True) -> TaskConfig:
    """Load a task by name (``tasks/<name>.yaml``) or path, resolving ``inherit`` chains.

    Every file must be a YAML mapping of known sections; a syntax error, an empty file, a list or a
    scalar, an ``inherit`` of a file that does not exist, and (with ``validate``, for a task that is
    not a ``_`` fragment) a missing ``env`` or ``agent`` section fail with one line naming the file,
    the line where YAML gives one, and what was expected.

    Args:
        task: task name or YAML path.
        overrides: optional dict deep-merged last (e.g. from the command line, ``cli.set_overrides``),
            recorded as "<override>" and checked like the file (its top-level keys too).
        validate: check every present section (:func:`register_task_check`: ``envs.validate.validate_task``):
            types, ranges, term functions and parameters, the agent section against rsl-rl.

    Raises:
        ConfigError: naming the file, the dotted key and what is allowed.
    """
    path = Path(task)
    if path.suffix not in (".yaml", ".yml"):
        path = TASKS_DIR / f"{task}.yaml"
        if str(task).startswith("_") and path.is_file():
            raise ConfigError(f"{task} is a shared fragment that tasks inherit, not a task; available: "
                              f"{available_tasks()}")
        if not path.is_file():
            raise ConfigError(f"unknown task {task!r}; available: {available_tasks()}")
    path = path.resolve()
    data, sources = _load_file(path, ())
    if overrides:
        unknown = sorted(str(k) for k in set(overrides) - set(TOP_LEVEL_KEYS))
        if unknown:
            raise ConfigError(f"<override>: unknown top-level keys {unknown}; allowed: {list(TOP_LEVEL_KEYS)}")
        _merge(data, overrides, sources, "<override>")
    loaded = TaskConfig(path.stem, path, data, sources)
    missing = [name for name in REQUIRED_SECTIONS if name not in data]
    if validate and missing and not path.name.startswith("_"):
        them = "it" if len(missing) == 1 else "them"
        raise ConfigError(f"{path}: no {' and no '.join(repr(m) for m in missing)} section (in the file or what it "
                          f"inherits); a task needs {list(REQUIRED_SECTIONS)}: add {them}, or "
                          "`inherit: _common.yaml` (tasks/) for the shared ones")
    for check in _TASK_CHECKS if validate else ():
        check(loaded)
    return loaded


def save_resolved(task: TaskConfig, path: Path) -> None:
    """Write the resolved (merged) configuration next to a run's results."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        fh.write(f"# resolved task '{task.name}' from {task.path}\n")
        yaml.safe_dump(task.data, fh, sort_keys=False)
