"""The thesis-reproduction experiments: one script per table or figure, run from the repository root.

    python -m experiments.table14_warm_start_encodings --scale small

Each script writes its table, figure and config under ``results/experiments/<script>/`` (``--out``); the
shared machinery is in the ``*_common`` modules of each family (distillation, RL policies, warm starts) and
:mod:`experiments.output`. The package is not installed with ``dls_quadruped``: its default paths
(``docs/policies``, ``results/``) are the repository's, so it runs from a clone (docs/experiments.md).
"""
