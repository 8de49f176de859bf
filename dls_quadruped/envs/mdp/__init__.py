"""Term functions of the MDP, one module per manager (observations, rewards, terminations, commands,
events, curriculum) plus the reward kernels and frame helpers they share."""
