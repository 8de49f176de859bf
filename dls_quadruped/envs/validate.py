"""Check every section of a task when it loads, without building anything.

``load_task`` calls ``validate_task`` (the ``envs`` package registers it): the same resolvers the
managers use at build time run here (term functions, parameter names, types and ranges, manager keys),
plus the dataclass sections (``env``, ``scene``, ``terrain``, ``actions.latent``) and the ``agent``
section against rsl-rl. A bad value therefore fails with the file and dotted key before a run
directory, a simulator or a worker exists. Sections a file does not have (fragments such as
``_base_rewards.yaml``) are skipped.
"""

from __future__ import annotations

from dls_quadruped.envs.config import TaskConfig
from dls_quadruped.envs.value_checks import dataclass_from_dict


def validate_task(task: TaskConfig) -> None:
    """Raise ``ConfigError`` (file, dotted key, allowed values) for the first bad value of ``task``."""
    from dls_quadruped.envs.agent_config import check_agent_section
    from dls_quadruped.envs.env import EnvConfig
    from dls_quadruped.envs.managers.action import resolve_action_config
    from dls_quadruped.envs.managers.command import resolve_command
    from dls_quadruped.envs.managers.curriculum import resolve_curriculum
    from dls_quadruped.envs.managers.event import resolve_events
    from dls_quadruped.envs.managers.observation import resolve_groups
    from dls_quadruped.envs.managers.reward import resolve_rewards
    from dls_quadruped.envs.managers.scene import SceneConfig
    from dls_quadruped.envs.managers.termination import resolve_terminations
    from dls_quadruped.sim.terrain import TerrainConfig

    data = task.data
    for name, cls in (("env", EnvConfig), ("scene", SceneConfig), ("terrain", TerrainConfig)):
        if name in data:
            dataclass_from_dict(cls, task.section(name), task, name)
    checks = {
        "actions": resolve_action_config,
        "observations": resolve_groups,
        "commands": resolve_command,
        "rewards": resolve_rewards,
        "terminations": resolve_terminations,
        "events": resolve_events,
        "curriculum": resolve_curriculum,
        "agent": check_agent_section,
    }
    for name, check in checks.items():
        if name in data:
            check(task)
