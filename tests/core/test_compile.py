"""``core/compile.py``: when to compile, a function that cannot be compiled runs eagerly after one warning, and a
method written once is fused per instance (``fused_method``)."""

from __future__ import annotations

import warnings

import pytest
import torch

from dls_quadruped.core.compile import (
    RECOMPILE_LIMIT,
    Fused,
    FusedCache,
    compile_wanted,
    fused_method,
)


def test_compile_wanted_defaults_to_cuda_only_and_refuses_non_booleans():
    assert compile_wanted(None, "cuda:0") and not compile_wanted(None, "cpu")
    assert compile_wanted(True, "cpu") and not compile_wanted(False, "cuda")
    with pytest.raises(ValueError, match="compile must be true, false or null"):
        compile_wanted("yes", "cpu")


def _branchy(x: torch.Tensor) -> torch.Tensor:
    """Reads a value back and branches on it: dynamo cannot make one graph of it (fullgraph)."""
    if x.sum().item() > 0:
        return x * 2.0
    return x - 1.0


def test_a_function_that_does_not_compile_runs_eagerly_after_one_warning():
    f = Fused(_branchy, True, "branchy")
    x = torch.arange(3.0)
    with pytest.warns(RuntimeWarning, match="torch.compile of branchy failed, running it eagerly") as caught:
        assert torch.equal(f(x), x * 2.0)
    assert not f.compiled and f.error is not None
    # the whole error, not only its first line (inductor's first line names no cause)
    assert str(f.error) in str(caught[0].message) and len(str(f.error).splitlines()) > 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no second warning
        assert torch.equal(f(-x - 1.0), -x - 2.0)


def test_disabled_is_the_function_itself_and_its_errors_pass_through():
    def bad(x):
        raise ValueError("mine")

    f = Fused(bad, False)
    assert not f.compiled
    with pytest.raises(ValueError, match="mine"):
        f(torch.zeros(1))
    assert torch.equal(Fused(_branchy, False)(torch.ones(2)), torch.full((2,), 2.0))


@pytest.mark.slow
def test_a_compiled_function_gives_the_eager_results():
    def f(a, b, out):
        out.copy_(torch.sin(a) * b + a.square())
        return (out * 3.0).sum(dim=1)

    g = torch.Generator().manual_seed(0)
    a, b = torch.randn(8, 5, generator=g, dtype=torch.float64), torch.randn(8, 5, generator=g, dtype=torch.float64)
    o1, o2 = torch.zeros_like(a), torch.zeros_like(a)
    fused = Fused(f, True, "f")
    r = fused(a, b, o2)
    assert fused.compiled
    assert torch.allclose(r, f(a, b, o1), rtol=1e-13, atol=0) and torch.allclose(o1, o2, rtol=1e-13, atol=0)


def test_a_fused_cache_keeps_one_fused_per_function_with_its_setting():
    def double(x):
        return x * 2.0

    eager, compiled = FusedCache(False), FusedCache(True)
    f = eager(double, "double")
    assert eager(double) is f and eager(_branchy) is not f  # one per function, made on first use
    assert not f.compiled and f.name == "double" and torch.equal(f(torch.ones(2)), torch.full((2,), 2.0))
    g = compiled(double, dynamic=True)
    assert g.compiled and g is not f and compiled(double) is g  # the cache's setting, not the caller's


def test_a_dynamic_function_runs_eagerly_once_before_it_is_traced_and_the_recompile_limit_is_raised():
    f = Fused(_branchy, True, "branchy", dynamic=True)  # does not compile: shows when tracing happens
    x = torch.arange(3.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the first call is the function itself: no trace, no warning
        assert torch.equal(f(x), x * 2.0)
    assert f.compiled
    with pytest.warns(RuntimeWarning, match="torch.compile of branchy failed"):  # traced on the second call
        assert torch.equal(f(-x - 1.0), -x - 2.0)
    assert torch._dynamo.config.recompile_limit >= RECOMPILE_LIMIT


class _Scaled:
    """Two fused methods (one static), one of them calling the other's eager function, as ``PhysicsRate`` does."""

    def __init__(self, compile: bool, scale: float):
        self.compile, self.scale, self.calls = compile, scale, 0

    @fused_method("Scaled.branchy")
    def _branchy(self, x: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        return _branchy(x) * self.scale

    @fused_method("Scaled.offset")
    @staticmethod
    def _offset(x: torch.Tensor) -> torch.Tensor:
        return x + 1.0


class _Nested:
    def __init__(self, owner: _Scaled):
        self.owner = owner

    @fused_method("Nested.double", enabled="owner.compile")
    def _double(self, x: torch.Tensor) -> torch.Tensor:
        return x * 2.0

    @fused_method("Nested.half", enabled=lambda n: getattr(n.owner, "compile", False))
    def _half(self, x: torch.Tensor) -> torch.Tensor:
        return x / 2.0


def test_a_fused_method_is_one_fused_per_instance_with_the_instances_setting():
    eager, other = _Scaled(False, 3.0), _Scaled(False, 5.0)
    f = eager._branchy
    assert isinstance(f, Fused) and eager._branchy is f and other._branchy is not f  # made once, per instance
    assert not f.compiled and f.name == "Scaled.branchy"
    x = torch.arange(3.0)
    assert torch.equal(f(x), x * 6.0) and torch.equal(other._branchy(x), x * 10.0)  # bound to its own instance
    assert torch.equal(f.fn(x), x * 6.0) and eager.calls == 2  # .fn: the method itself, eager
    assert torch.equal(eager._offset(x), x + 1.0) and torch.equal(eager._offset.fn(x), x + 1.0)
    assert isinstance(_Scaled._branchy, fused_method)  # on the class: the decorator itself
    assert _Nested(_Scaled(True, 1.0))._double.compiled and not _Nested(eager)._double.compiled  # a dotted setting
    assert _Nested(_Scaled(True, 1.0))._half.compiled and not _Nested(object())._half.compiled  # a function of it


def test_a_fused_method_falls_back_to_its_eager_method_and_refuses_a_non_boolean_setting():
    compiled = _Scaled(True, 2.0)
    x = torch.arange(3.0)
    with pytest.warns(RuntimeWarning, match="torch.compile of Scaled.branchy failed, running it eagerly"):
        assert torch.equal(compiled._branchy(x), x * 4.0)
    assert not compiled._branchy.compiled and torch.equal(compiled._branchy(-x - 1.0), (-x - 2.0) * 2.0)
    with pytest.raises(TypeError, match="_Scaled's enabled attribute must be a bool, got None"):
        _ = _Scaled(None, 1.0)._offset  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="decorates one function"):
        fused_method("twice")(_branchy)(_branchy)


class _Warmed:
    """A fused method whose first call per instance runs eagerly (``eager_first``), as the env's reset bookkeeping."""

    def __init__(self, compile: bool):
        self.compile = compile

    @fused_method("Warmed.branchy", eager_first=True)
    def _branchy(self, x: torch.Tensor) -> torch.Tensor:
        return _branchy(x)


def test_a_fused_method_runs_eagerly_first_when_asked_and_is_made_anew_after_renew():
    warmed = _Warmed(True)
    f, x = warmed._branchy, torch.arange(3.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the first call is the method itself: no trace, no warning
        assert torch.equal(f(x), x * 2.0)
    with pytest.warns(RuntimeWarning, match="torch.compile of Warmed.branchy failed"):  # traced on the second call
        assert torch.equal(f(-x - 1.0), -x - 2.0)
    assert not f.compiled
    _Warmed._branchy.renew(warmed)
    warmed.compile = False  # the setting is read again by the new one
    g = warmed._branchy
    assert g is not f and not g.compiled and g.error is None and warmed._branchy is g
    _Warmed._branchy.renew(_Warmed(True))  # an instance without one made: nothing to drop
