"""core/registry.py: the one "look it up by name" pattern, and the tables built on it (backends, MPC kernels,
evaluation scenarios)."""

from __future__ import annotations

import pytest

from dls_quadruped.core.registry import Registry


def _fruit() -> Registry[int]:
    reg: Registry[int] = Registry("fruit")
    reg.register("apple", 1, "red")
    reg.register("pear", 2)
    return reg


def test_get_returns_the_object_and_names_keep_registration_order():
    reg = _fruit()
    reg.register("fig", 3, "purple")
    assert reg.get("pear") == 2 and reg.get("fig") == 3
    assert reg.names() == ("apple", "pear", "fig") and list(reg) == ["apple", "pear", "fig"]
    assert reg.description("apple") == "red" and reg.description("pear") == ""
    assert "apple" in reg and "plum" not in reg and ["apple"] not in reg and len(reg) == 3


@pytest.mark.parametrize("name", ["plum", "", None, 3, ["apple"]])
def test_an_unknown_name_is_one_line_naming_the_allowed_ones(name):
    with pytest.raises(ValueError) as err:
        _fruit().get(name)
    assert str(err.value) == f"unknown fruit {name!r}; allowed: apple (red), pear"
    assert "\n" not in str(err.value)


def test_a_name_is_registered_once():
    reg = _fruit()
    with pytest.raises(ValueError, match="^fruit 'apple' is already registered$"):
        reg.register("apple", 9, "green")
    assert reg.get("apple") == 1  # the first registration stands
    for bad in ("", None, 5):
        with pytest.raises(ValueError, match="fruit name must be a non-empty string"):
            reg.register(bad, 9)


def test_unregister_and_replace():
    reg = _fruit()
    reg.unregister("apple")
    reg.unregister("never")  # unknown names are ignored
    assert reg.names() == ("pear",)
    reg.register("apple", 5, "green")  # free again, now last
    reg.replace("pear", 7)
    assert reg.names() == ("pear", "apple") and reg.get("pear") == 7 and reg.description("pear") == ""
    with pytest.raises(ValueError, match="unknown fruit 'plum'"):
        reg.replace("plum", 1)


def test_the_mapping_view_is_live_and_refuses_new_names():
    reg = _fruit()
    view = reg.as_mapping()
    assert dict(view) == {"apple": 1, "pear": 2}
    reg.register("fig", 3)
    assert "fig" in view and view["fig"] == 3 and list(view) == ["apple", "pear", "fig"]
    view["apple"] = 10  # what monkeypatch.setitem does: swaps the object, keeps the description
    assert reg.get("apple") == 10 and reg.description("apple") == "red"
    with pytest.raises(KeyError):
        view["plum"] = 4
    with pytest.raises(KeyError):
        view["plum"]
    del view["fig"]
    assert reg.names() == ("apple", "pear")


def test_the_simulator_backends_are_a_registry():
    from dls_quadruped.sim import registry as R

    assert R.backend_names() == R.BACKENDS.names() and R.backend_names()[0] == "cpu"
    with pytest.raises(ValueError, match=r"^unknown simulator backend 'gpu'; allowed: cpu \(MuJoCo C batch"):
        R.make_backend("gpu", None, 1)


def test_the_mpc_kernels_are_a_registry_and_the_sampler_calls_the_registered_one(monkeypatch):
    import torch

    from dls_quadruped.bench.mpc_common import solve_problem
    from dls_quadruped.mpc import SamplerConfig, SamplingMPC, warm_start
    from dls_quadruped.mpc.config import KERNELS
    from dls_quadruped.mpc.kernel import reference_costs
    from dls_quadruped.mpc.kernel_registry import KERNEL_REGISTRY

    assert tuple(KERNELS) == ("fast", "reference", "cpp", "warp") == KERNEL_REGISTRY.names()
    with pytest.raises(ValueError, match=r"kernel must be one of \('fast', 'reference', 'cpp', 'warp'\), got 'gpu'"):
        SamplerConfig(kernel="gpu")
    calls = []

    def counting(inp, cfg, model):
        calls.append(inp.warm_starts.shape)
        return reference_costs(inp, cfg, model)

    KERNEL_REGISTRY.register("counting", counting, "reference, counted (tests)")
    try:
        cfg = SamplerConfig(num_samples=64, horizon=5, kernel="counting")
        state, refs, phase = solve_problem("cpu")
        mpc = SamplingMPC(cfg, seed=0)
        result = mpc.solve(state, refs, [warm_start.nominal_trot(1, cfg)], phase=phase)
        ref = SamplingMPC(SamplerConfig(num_samples=64, horizon=5, kernel="reference"), seed=0)
        want = ref.solve(state, refs, [warm_start.nominal_trot(1, cfg)], phase=phase)
    finally:
        KERNEL_REGISTRY.unregister("counting")
    assert len(calls) == 1 and tuple(calls[0][:2]) == (1, 1)  # one solve: B = 1 robot, G = 1 warm start
    assert torch.equal(result.best_encoded, want.best_encoded) and torch.equal(result.best_cost, want.best_cost)


def test_the_scenarios_are_a_registry():
    from dls_quadruped.eval.scenarios import SCENARIO_REGISTRY, SCENARIOS

    assert list(SCENARIOS) == list(SCENARIO_REGISTRY.names()) and {"simple", "survival", "gait"} <= set(SCENARIOS)
    assert all(SCENARIO_REGISTRY.description(s.name) == s.description for s in SCENARIOS.values())
    with pytest.raises(ValueError, match=r"^unknown evaluation scenario 'survive'; allowed: simple \("):
        SCENARIO_REGISTRY.get("survive")
