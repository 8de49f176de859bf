"""Variants of a loaded task made by replacing whole top-level sections (scenarios, distillation)."""

from __future__ import annotations

import copy
import dataclasses

from dls_quadruped.envs.config import TaskConfig


def replace_sections(task: TaskConfig, sections: dict, source: str) -> TaskConfig:
    """A copy of ``task`` whose top-level ``sections`` are replaced whole (not deep-merged), their
    provenance recorded as ``source``."""
    data = copy.deepcopy(task.data)
    data.update(copy.deepcopy(sections))
    sources = {k: v for k, v in task.sources.items() if k.split(".")[0] not in sections}
    sources.update({name: source for name in sections})
    return dataclasses.replace(task, data=data, sources=sources)
