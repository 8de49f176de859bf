"""A broken task file is one line naming the file, the line (where YAML gives one) and what was expected.

One case per way a newcomer breaks a file: YAML syntax (tab, bad indent, unclosed bracket), an empty
file, a list or a scalar at the top level, a task without ``env`` or ``agent``, an ``inherit`` of a
file that does not exist. The command lines keep their rule: one line on stderr, exit 2.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from dls_quadruped.cli import run_cli
from dls_quadruped.envs.config import TASKS_DIR, ConfigError, load_task
from dls_quadruped.learning import train

BASE = TASKS_DIR / "base.yaml"

# name: (file text, expected start of the message after "<file>", words it must contain)
CASES = {
    "tab": ("env:\n\tnum_envs: 4\n", ":2:1: invalid YAML: found a tab character", ["spaces"]),
    "tab_after_key": (f"inherit: {BASE}\nenv:\n  num_envs:\t4\n", ":3:12: invalid YAML: found a tab", ["spaces"]),
    "bad_indent": (f"inherit: {BASE}\nenv:\n  num_envs: 4\n   decimation: 4\n",
                   ":4:14: invalid YAML: mapping values are not allowed here", ["indented"]),
    "dedent_in_section": (f"inherit: {BASE}\nenv:\n  num_envs: 4\n decimation: 4\n",
                          ":4:2: invalid YAML: expected <block end>", ["starts on line 1", "indented"]),
    "unclosed_bracket": (f"inherit: {BASE}\nterrain:\n  types: [flat, rugged\n",
                         ":4:1: invalid YAML: expected ',' or ']'", ["starts on line 3", "every [ and { closed"]),
    "unclosed_brace": (f"inherit: {BASE}\nenv: {{num_envs: 4\nagent: {{}}\n",
                       ":3:6: invalid YAML: expected ',' or '}'", ["starts on line 2"]),
    "empty": ("", ": the file is empty (or only comments); expected a mapping of sections", ["'env'", "'agent'"]),
    "only_comments": ("# nothing yet\n", ": the file is empty (or only comments)", ["'rewards'"]),
    "list": ("# sections\n- env\n- agent\n", ":2: the top level is a list; expected a mapping of sections", []),
    "scalar": ("base\n", ":1: the top level is a single value (str 'base'); expected a mapping", []),
    "no_agent": (f"inherit: {BASE}\nagent: null\n", (": no 'agent' section (in the file or what it inherits); "
                              "a task needs ['env', 'agent']: add it"), ["_common.yaml"]),
    "no_env": (f"inherit: {BASE}\nenv: null\n", ": no 'env' section", ["a task needs ['env', 'agent']"]),
    "no_env_no_agent": ("rewards: {}\n", ": no 'env' and no 'agent' section", ["add them"]),
    "missing_inherit": ("# my task\ninherit: [_base.yaml]\nenv: {}\n",
                        ":2: inherit: '_base.yaml' not found (no file ", ["files next to it: ["]),
    "inherit_not_a_name": ("inherit: {file: base.yaml}\n", (":1: inherit: expected a file name or a list "
                                                            "of file names, got {'file': 'base.yaml'}"), []),
    "unknown_section": (f"inherit: {BASE}\nenv: {{}}\nreward: {{}}\n", (":3: unknown top-level keys "
                                                                        "['reward']; allowed: ['inherit', 'env'"), []),
}


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "mine.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("case", list(CASES))
def test_broken_task_file_is_one_line_with_file_and_line(tmp_path, case):
    text, start, words = CASES[case]
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_task(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}{start}"), message
    for word in words:
        assert word in message, message


def test_missing_sections_are_allowed_in_fragments_and_without_validation(tmp_path):
    fragment = tmp_path / "_rewards.yaml"
    fragment.write_text("rewards: {}\n")
    assert load_task(fragment).data == {"rewards": {}}  # a `_` fragment (e.g. the eval reward file) loads alone
    assert load_task(_write(tmp_path, "rewards: {}\n"), validate=False).data == {"rewards": {}}


def test_fragment_name_is_not_a_task():
    with pytest.raises(ConfigError, match=r"^_common is a shared fragment that tasks inherit, not a task; "
                                          r"available: \['base'"):
        load_task("_common")


@pytest.mark.parametrize("case", ["tab", "empty", "no_agent", "missing_inherit"])
def test_train_reports_a_broken_task_file_as_one_line(tmp_path, capsys, case):
    path = _write(tmp_path, CASES[case][0])
    with pytest.raises(SystemExit) as exit_:
        run_cli(train.main, ["--task", str(path), "--log-root", str(tmp_path / "runs")])
    assert exit_.value.code == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    assert f": error: {path}:" in lines[0] or f": error: {path}: " in lines[0], lines[0]
    assert not (tmp_path / "runs").exists()
