"""A second RL library as a user would run it: Stable-Baselines3 (not a dependency; skipped where it is not
installed) checks the one-robot view with its own ``check_env``, with the normalised action space, trains PPO
for a few hundred steps, saves, loads and predicts (docs/gymnasium.md "Other RL libraries")."""

from __future__ import annotations

import numpy as np
import pytest

sb3 = pytest.importorskip("stable_baselines3", reason="Stable-Baselines3 is not installed (pip install "
                                                      "stable-baselines3)")


@pytest.mark.slow
def test_stable_baselines3_checks_trains_saves_and_loads(tmp_path):
    import warnings

    from stable_baselines3.common.env_checker import check_env

    from dls_quadruped.envs.gym_env import LocomotionGymEnv

    env = LocomotionGymEnv("base", num_workers=0, seed=0, normalize_actions=True)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env)
        assert not [w for w in caught if "symmetric and normalized" in str(w.message)]  # the box is [-1, 1]
        model = sb3.PPO("MultiInputPolicy", env, n_steps=128, batch_size=64, n_epochs=1, seed=0, device="cpu")
        model.learn(total_timesteps=256)
        model.save(tmp_path / "ppo")
        loaded = sb3.PPO.load(tmp_path / "ppo", device="cpu")
        obs, _ = env.reset(seed=1)
        action, _ = loaded.predict(obs, deterministic=True)
        assert action.shape == (28,) and np.all(np.abs(action) <= 1.0)
        np.testing.assert_array_equal(action, model.predict(obs, deterministic=True)[0])
    finally:
        env.close()
