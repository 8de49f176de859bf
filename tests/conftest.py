"""Fixtures shared by the test packages."""

from __future__ import annotations

import pytest

SMALL_TERRAIN = {"scene": {"num_workers": 0},
                 "terrain": {"num_rows": 3, "tile_size": 4.0, "border": 1.0, "platform": 1.0}}
"""Task overrides for a quick in-process base env: no simulator workers, a 3-row terrain."""


@pytest.fixture(scope="module")
def small_base_env():
    """The base task on 3 robots with :data:`SMALL_TERRAIN`, one per test module."""
    from dls_quadruped.envs.config import load_task
    from dls_quadruped.envs.env import LocomotionEnv

    e = LocomotionEnv(load_task("base", overrides=SMALL_TERRAIN), num_envs=3, verbose=False)
    yield e
    e.close()
