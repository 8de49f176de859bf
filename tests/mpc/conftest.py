"""Fixtures of the MPC tests (the standing robot itself is ``tests/conftest.py``'s ``standing``)."""

from __future__ import annotations

import pytest

from dls_quadruped.mpc.cost import Refs
from dls_quadruped.mpc.srbd import SRBDState


@pytest.fixture
def standing_pair(standing) -> tuple[SRBDState, Refs]:
    """Two standing robots and their references."""
    return standing(2)
