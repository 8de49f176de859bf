"""list_tasks: one line per task of tasks/, its description the first sentence of the file's opening comment."""

from __future__ import annotations

from dls_quadruped import list_tasks
from dls_quadruped.envs.config import TASKS_DIR, available_tasks, task_description


def test_one_line_per_task_with_its_description(capsys):
    lines = list_tasks.main([])
    assert capsys.readouterr().out.splitlines() == lines
    names = available_tasks()
    assert [line.split()[0] for line in lines] == names and "base" in names and "_common" not in names
    width = max(map(len, names))
    first = (TASKS_DIR / "base.yaml").read_text().splitlines()[0]  # one sentence on one line in base.yaml
    assert lines[names.index("base")] == f"{'base':<{width}}  {first.removeprefix('# ')}"
    assert all(len(line) > width + 2 for line in lines)  # every registered task has a description


def test_task_description_reads_the_opening_sentence(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text("# Stairs, second stage: the climb task with no entropy\n# bonus. Start it from a climb run:\n"
                    "#   make train TASK=t\ninherit: base.yaml\n")
    assert task_description(path) == "Stairs, second stage: the climb task with no entropy bonus."
    path.write_text("# Rough from the base expert (docs/experts.md):\n#   make train TASK=t INIT_STD=1.0\n# More.\n")
    assert task_description(path) == "Rough from the base expert (docs/experts.md)"
    path.write_text("inherit: base.yaml  # not an opening comment\n")
    assert task_description(path) == ""
