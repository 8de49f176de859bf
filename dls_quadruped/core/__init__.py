"""Types and frame math shared by every layer (robots -> core -> control -> sim -> envs -> mpc).

``state.RobotState`` is what the simulator publishes and what controllers read; ``rotations``
holds the (w, x, y, z) quaternion and Euler helpers. Nothing here imports another layer.
"""
