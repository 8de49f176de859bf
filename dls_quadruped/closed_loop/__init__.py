"""Policy-warm-started sampling MPC in the closed loop (thesis 3.1-3.2, 7.3).

``controllers`` (rl_warm_start, naive_warm_start, rl_baseline, student; by name in ``registry``; their settings in
``controller_config``), ``loop`` (one controller's batched episodes in a ``LocomotionEnv`` and their traces),
``episodes`` (the scenarios' envs, every controller on
the same episodes, summaries, plot), ``metrics`` (medians and quartiles, 7.3.1);
command line: ``python -m dls_quadruped.closed_loop`` (docs/closed_loop.md).
"""
