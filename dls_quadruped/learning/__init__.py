"""PPO training (rsl-rl-lib), distillation and policy export.

Importing the package makes OpenMP's idle threads sleep instead of spin (``OMP_WAIT_POLICY=PASSIVE``,
unless the environment already sets it; it must be set before torch loads): the trainer's update runs
on every core while the simulator workers idle (``learning/fast_update.py``), and on a machine whose
cores other processes share, spinning threads made two threads 3-5x slower than one.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
