"""Curriculum terms (thesis 4.3.3): ``term(env, env_mask, **params) -> Tensor`` (a 0-dim value on the env's
device, logged), called for the envs being reset, a (B,) bool mask, before their episode sums are cleared. Each
term is also called once when the env is built, with no env in the mask, so it can set its initial state.
Decisions are made on the device (static shapes, nothing read back during the step); the host copies of what a
term changes (reward weights, command ranges) are read when a checkpoint is saved.
"""

from __future__ import annotations

import torch


def terrain_levels(env, env_mask: torch.Tensor, up_fraction: float = 0.5, down_fraction: float = 0.5
                   ) -> torch.Tensor:
    """Move a robot one row up when it walked further than ``up_fraction`` x tile size from its
    origin; down when it fell, or when it walked less than ``down_fraction`` x its *commanded
    displacement* (``CommandManager.commanded_disp``: how far from its origin a robot that tracked
    every command of the episode exactly would be).

    The commanded displacement, not |v| x episode length: a command (v, omega) is an arc of radius
    |v| / |omega|, whose chord after 15 s is below half of |v| x 15 s for every |omega| > 0.27 rad/s,
    so the straight-line rule demoted a perfect tracker on two thirds of the rough task's commands
    (omega ~ U[-0.8, 0.8]). A fall (the episode ended before its time-out) demotes unless the robot
    had already walked far enough to go up. A robot that solves the hardest row is sent to a random
    row (keeps the hardest rows in use without forgetting). Returns the mean level (0-dim).
    """
    scene = env.scene
    dist = torch.linalg.vector_norm(env.state.base_pos_w[:, :2] - scene.env_origins[:, :2], dim=-1)
    asked = torch.linalg.vector_norm(env.command_manager.commanded_disp, dim=-1)
    fell = ~env.termination_manager.time_outs & (env.episode_length_buf > 0)
    up = dist > up_fraction * scene.terrain.cfg.tile_size
    down = ((dist < down_fraction * asked) | fell) & ~up
    scene.update_levels(env_mask, up.long() - down.long())
    return scene.terrain_levels.float().mean()


def command_speed_growth(env, env_mask: torch.Tensor, reward_term: str, threshold: float, step: float,
                         max_speed: float, component: str = "lin_vel_x") -> torch.Tensor:
    """Speed task: raise the upper end of the forward-speed range by ``step`` [m/s] (up to
    ``max_speed``) when the reset envs tracked velocity well: mean episode reward of ``reward_term``
    above ``threshold`` x its maximum (weight x episode length). Returns the current upper bound (0-dim, float64).

    The range is the command manager's device tensor (``CommandManager.range``), which its samplers read."""
    rng = env.command_manager.range(component)  # (2,) float64, [low, high] [m/s]
    grow = env.reward_manager.episode_fraction(reward_term, env_mask) > threshold
    rng[1:].copy_(torch.where(grow, (rng[1:] + step).clamp(max=max_speed), rng[1:]))
    return rng[1].clone()


def penalties_when_walking(env, env_mask: torch.Tensor, terms: list[str], reward_term: str,
                           threshold: float) -> torch.Tensor:
    """Keep the reward ``terms`` (action rate, action limits) at weight 0 until the policy walks:
    the mean episode reward of ``reward_term`` over the reset envs exceeds ``threshold`` x its maximum; then
    switch them to their task weights for good. Returns 1.0 once enabled (0-dim)."""
    rm = env.reward_manager
    state = env.curriculum_manager.state.setdefault("penalties_when_walking", {})
    if "targets" not in state:  # first (build-time) call: remember the task weights, switch off
        state["targets"] = {t: rm.weights[t] for t in terms}
        state["enabled"] = False
        for t in terms:
            rm.weights[t] = 0.0
    if not isinstance(state["enabled"], torch.Tensor):  # built, or loaded from a checkpoint: a flag on the device
        with torch.inference_mode(False):  # a normal tensor even in rsl-rl's rollouts: updated in place below
            state["enabled"] = torch.tensor(bool(state["enabled"]), device=env.device)
    # in place: a step replayed from a captured graph reads the flag where the capture read it (envs/env_graph.py)
    enabled = state["enabled"]
    enabled |= rm.episode_fraction(reward_term, env_mask) > threshold
    rm.weights.switch(state["targets"], enabled)
    return enabled.float()
