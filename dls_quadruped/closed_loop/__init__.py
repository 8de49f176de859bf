"""Policy-warm-started sampling MPC in the closed loop (thesis 3.1-3.2, 7.3).

``controllers`` (rl_warm_start, naive_warm_start, rl_baseline, student, each its own class of the controller
protocol, ``envs/controller.py``; the MPC ones in ``mpc_controllers``, their configured base in
``controller_base``; by name in ``registry``; their settings in ``controller_config``), ``loop`` (one
controller's batched episodes in a ``LocomotionEnv`` and their traces), ``episodes`` (the scenarios' envs, every
controller on the same episodes, summaries, plot), ``metrics`` (medians and quartiles, 7.3.1), ``baseline_run``
(the model-based baseline in the home task); command line: ``python -m dls_quadruped.closed_loop``
(docs/closed_loop.md).
"""
