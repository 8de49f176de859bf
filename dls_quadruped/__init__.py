"""dls_quadruped: latent-action quadruped locomotion with RL policies and a batched sampling MPC."""

__version__ = "0.1.0"
