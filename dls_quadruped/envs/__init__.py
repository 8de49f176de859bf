"""The manager-based environment: task files, managers, MDP terms, the env and its gymnasium view.

Importing the package registers the task checks that need the managers (``validate.py``) with the task
loader (``config.py``), so ``load_task`` checks every section while ``config.py``, which the managers
import, imports none of them.
"""

from dls_quadruped.envs.config import register_task_check
from dls_quadruped.envs.validate import validate_task

register_task_check(validate_task)
