"""tools/wheelhouse.py: the closure of an install, read from the installed distributions."""

from __future__ import annotations

import pytest
from packaging.requirements import Requirement

from dls_quadruped.tools import wheelhouse as W


def test_the_base_closure_holds_every_direct_requirement_at_its_installed_version():
    from importlib.metadata import version

    pins = W.closure("dls_quadruped", set(), set(), "3.11")
    for name in ("torch", "mujoco", "gymnasium", "rsl-rl-lib", "pin", "numpy", "matplotlib", "pyyaml"):
        assert pins[name] == version(name), name
    assert "mujoco-warp" not in pins and "pytest" not in pins  # extras only when asked for


def test_an_excluded_distribution_takes_what_only_it_needs_along():
    full = W.closure("dls_quadruped", set(), set(), "3.11")
    without = W.closure("dls_quadruped", set(), {"torch"}, "3.11")
    assert "torch" in full and "torch" not in without
    assert "networkx" in full and "networkx" not in without  # torch's own requirement, nobody else's here
    assert "numpy" in without  # still needed by mujoco and others


def test_markers_are_evaluated_for_the_target_python_not_this_one():
    req = Requirement('tomli>=1; python_version < "3.12"')
    assert W._applies(req, set(), "3.11") and not W._applies(req, set(), "3.12")
    extra = Requirement('onnx; extra == "dev"')
    assert W._applies(extra, {"dev"}, "3.12") and not W._applies(extra, set(), "3.12")


def test_a_needed_distribution_that_is_not_installed_is_named(monkeypatch):
    from importlib import metadata

    real = metadata.distribution

    def fake(name):
        if W.canonical(name) == "gymnasium":
            raise metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(metadata, "distribution", fake)
    with pytest.raises(RuntimeError, match="gymnasium is needed but not installed"):
        W.closure("dls_quadruped", set(), set(), "3.11")


def test_names_are_normalised():
    assert W.canonical("Rsl_RL.lib") == "rsl-rl-lib"


def test_bad_python_version_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as err:
        W.main(["--python-version", "312", "--list"])
    assert err.value.code == 2 and "--python-version must look like 3.12" in capsys.readouterr().err
