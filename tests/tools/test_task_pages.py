"""docs/tasks/<task>.md against tasks/*.yaml: every task has a page, and each page's generated tables are what
``python -m dls_quadruped.tools.task_pages`` makes from the resolved task now (a changed weight, term or range
in a task file fails here until the page is regenerated). The generator itself is checked on one task's values
read by hand from its YAML files."""

from __future__ import annotations

import pytest

from dls_quadruped.envs.config import available_tasks
from dls_quadruped.tools import task_pages


def test_every_task_has_a_page_that_matches_its_task_file():
    expected = task_pages.expected_pages()
    assert {p.stem for p in expected} == {*available_tasks(), "index"}
    stale = [p.name for p, text in expected.items() if p.read_text() != text]
    assert not stale, f"regenerate with python -m dls_quadruped.tools.task_pages: {stale}"


def test_the_tables_carry_the_yaml_values():
    text = task_pages.task_tables("climb")
    # tasks/climb.yaml: track_lin_vel_xy through track_lin_vel_xy_soft, weight 1.5, alpha_max 0.5
    assert ("| `track_lin_vel_xy` | `track_lin_vel_xy_soft` | 1.5 | sigma = 0.5, alpha_max = 0.5 | "
            "`tasks/climb.yaml` |") in text
    # tasks/_low_perturbation.yaml: pushes every 8-12 s; tasks/climb.yaml: stairs of 5-50 cm, 10 rows
    assert "| `push` | `push_robot` | interval, every [8, 12] s | velocity_range = [-0.1667, 0.1667] |" in text
    assert "**Terrain**: `stairs_up`, `stairs_down`; num_rows = 10, step_height = [0.05, 0.5]" in text
    assert "noise scale 0.3333" in text and "mirror symmetry on" in text
    base = task_pages.task_tables("base")
    assert "| `joint_soft_limits` | `joint_soft_limits` | -3 | - | `tasks/_base_rewards.yaml` |" in base
    assert "**Curricula**:" in base and "`penalties_when_walking`" in base and "`terrain_levels`" not in base
    assert "entropy coefficient 0.005" in task_pages.task_tables("base_thesis")


def test_a_page_without_its_markers_is_named(tmp_path):
    page = tmp_path / "x.md"
    with pytest.raises(ValueError, match="x.md: no generated block"):
        task_pages.render("# x\n", "table", page)
    assert task_pages.render(f"# x\n{task_pages.BEGIN}\nold\n{task_pages.END}\ntail", "new", page) == \
        f"# x\n{task_pages.BEGIN}\nnew\n{task_pages.END}\ntail"
