"""List the registered tasks, one line each: name and the first sentence of its file's opening comment.

    python -m dls_quadruped.list_tasks
    make tasks

A task is a ``tasks/<name>.yaml`` not starting with ``_`` (``envs.config.available_tasks``); train, play and
eval take its name (``--task rough``) or any task file's path.
"""

from __future__ import annotations

import argparse

from dls_quadruped.cli import ArgumentParser, run_cli
from dls_quadruped.envs.config import TASKS_DIR, available_tasks, task_description


def task_lines() -> list[str]:
    """``<name>  <description>`` for every task, names padded to one column."""
    names = available_tasks()
    width = max(map(len, names), default=0)
    return [f"{name:<{width}}  {task_description(TASKS_DIR / f'{name}.yaml') or '(no description)'}" for name in names]


def main(argv: list[str] | None = None) -> list[str]:
    ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    lines = task_lines()
    print("\n".join(lines))
    return lines


if __name__ == "__main__":
    run_cli(main)
