"""The task loader runs the checks the ``envs`` package registers, whatever else the caller imported.

``envs/config.py`` imports no manager (the managers import it); ``envs/__init__.py`` registers
``envs/validate.py`` with it. A fresh interpreter that imports only ``load_task`` must still get every
section checked, the manager terms' and the agent section's alike.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import yaml

from dls_quadruped.envs import validate
from dls_quadruped.envs.config import _TASK_CHECKS, TASKS_DIR

PROBE = """
import json, sys
from dls_quadruped.envs.config import ConfigError, load_task
out = {"env_imported_with_the_loader": "dls_quadruped.envs.env" in sys.modules, "errors": []}
for path in sys.argv[1:]:
    try:
        load_task(path)
        out["errors"].append(None)
    except ConfigError as err:
        out["errors"].append(str(err))
print(json.dumps(out))
"""


def test_validate_task_is_registered_once():
    assert _TASK_CHECKS.count(validate.validate_task) == 1


def test_a_fresh_interpreter_checks_every_section(tmp_path: Path):
    bodies = {"reward": {"rewards": {"track_lin_vel_xy": {"params": {"sigma": 0.0}}}},
              "agent": {"agent": {"num_step_per_env": 24}},
              "good": {}}
    paths = []
    for name, body in bodies.items():
        paths.append(tmp_path / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump({"inherit": str(TASKS_DIR / "base.yaml"), **body}))
    run = subprocess.run([sys.executable, "-c", PROBE, *map(str, paths)], capture_output=True, text=True,
                         timeout=120, check=True)
    out = json.loads(run.stdout.splitlines()[-1])
    assert out["env_imported_with_the_loader"] is False
    reward, agent, good = out["errors"]
    assert reward.startswith(f"{paths[0]}: rewards.track_lin_vel_xy.params.sigma: must be > 0"), reward
    assert agent.startswith(f"{paths[1]}: agent.num_step_per_env: unknown key"), agent
    assert good is None
