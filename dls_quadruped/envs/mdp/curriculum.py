"""Curriculum terms (thesis 4.3.3): ``term(env, env_ids, **params) -> float | Tensor`` (logged), called for the
envs being reset, before their episode sums are cleared. Each term is also called once when the
env is built, with empty ``env_ids``, so it can set its initial state.
"""

from __future__ import annotations

import torch


def terrain_levels(env, env_ids: torch.Tensor, up_fraction: float = 0.5, down_fraction: float = 0.5) -> float:
    """Move a robot one row up when it walked further than ``up_fraction`` x tile size from its
    origin; down when it fell, or when it walked less than ``down_fraction`` x its *commanded
    displacement* (``CommandManager.commanded_disp``: how far from its origin a robot that tracked
    every command of the episode exactly would be).

    The commanded displacement, not |v| x episode length: a command (v, omega) is an arc of radius
    |v| / |omega|, whose chord after 15 s is below half of |v| x 15 s for every |omega| > 0.27 rad/s,
    so the straight-line rule demoted a perfect tracker on two thirds of the rough task's commands
    (omega ~ U[-0.8, 0.8]). A fall (the episode ended before its time-out) demotes unless the robot
    had already walked far enough to go up. A robot that solves the hardest row is sent to a random
    row (keeps the hardest rows in use without forgetting). Returns the mean level, a 0-dim tensor on the env's
    device (logging it reads nothing back during the step).
    """
    scene = env.scene
    if len(env_ids) > 0:
        dist = torch.linalg.vector_norm(env.state.base_pos_w[env_ids, :2] - scene.env_origins[env_ids, :2], dim=-1)
        asked = torch.linalg.vector_norm(env.command_manager.commanded_disp[env_ids], dim=-1)
        fell = ~env.termination_manager.time_outs[env_ids] & (env.episode_length_buf[env_ids] > 0)
        up = dist > up_fraction * scene.terrain.cfg.tile_size
        down = ((dist < down_fraction * asked) | fell) & ~up
        scene.update_levels(env_ids, up.long() - down.long())
    return scene.terrain_levels.float().mean()


def command_speed_growth(env, env_ids: torch.Tensor, reward_term: str, threshold: float, step: float,
                         max_speed: float, component: str = "lin_vel_x") -> float:
    """Speed task: raise the upper end of the forward-speed range by ``step`` [m/s] (up to
    ``max_speed``) when the reset envs tracked velocity well: mean episode reward of ``reward_term``
    above ``threshold`` x its maximum (weight x episode length). Returns the current upper bound."""
    cm = env.command_manager
    rng = list(cm.params[component])
    if len(env_ids) > 0:
        score = env.reward_manager.episode_fraction(reward_term, env_ids)
        if score > threshold:
            rng[1] = min(rng[1] + step, max_speed)
            cm.params[component] = rng
    return float(rng[1])


def penalties_when_walking(env, env_ids: torch.Tensor, terms: list[str], reward_term: str,
                           threshold: float) -> float:
    """Keep the reward ``terms`` (action rate, action limits) at weight 0 until the policy walks:
    the mean episode reward of ``reward_term`` exceeds ``threshold`` x its maximum; then switch them
    to their task weights for good. Returns 1.0 once enabled."""
    rm = env.reward_manager
    state = env.curriculum_manager.state.setdefault("penalties_when_walking", {})
    if "targets" not in state:  # first (build-time) call: remember the task weights, switch off
        state["targets"] = {t: rm.weights[t] for t in terms}
        state["enabled"] = False
        for t in terms:
            rm.weights[t] = 0.0
    if not state["enabled"] and len(env_ids) > 0 and rm.episode_fraction(reward_term, env_ids) > threshold:
        state["enabled"] = True
        rm.weights.update(state["targets"])
    return float(state["enabled"])
