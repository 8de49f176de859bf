"""``fused``: a torch function compiled into a few fused kernels where that is asked for, eager where not.

A physics step of the Warp backends runs ~200 small torch operators per robot batch (the low-level
controller, the leg kinematics, the divergence checks): on a GPU each is a kernel launch of a few
microseconds that the host has to issue, so the step is bound by the host, not the GPU (docs/gpu.md). Compiled
with ``torch.compile`` (``fullgraph=True``, static shapes: the number of robots is fixed per backend) the same
function is a handful of fused kernels (Triton on CUDA, C++ on the CPU) with the same results to round-off.

Compiling costs seconds on the first call (and a C++ compiler on the CPU), so it is opt-in where that cost is
not repaid: ``SimConfig.compile`` is None by default, meaning on for CUDA devices and off elsewhere. A function
that fails to compile (no compiler, an unsupported operator) runs eagerly from then on, after one
``RuntimeWarning`` naming it and the error: a run never stops because fusing did not work.

A method is written once and fused per instance with :func:`fused_method`::

    class PhysicsRate:
        def __init__(self, sim, compile):
            self.compile = compile_wanted(compile, sim.device)

        @fused_method("WarpSim settle")
        def _settle(self, qpos, qvel): ...

``self._settle(...)`` runs the instance's :class:`Fused` (compiled when ``self.compile``), ``self._settle.fn(...)``
the same method eagerly.
"""

from __future__ import annotations

import operator
import warnings
from collections.abc import Callable
from typing import Any

import torch


def compile_wanted(setting: bool | None, device: torch.device | str) -> bool:
    """Whether to compile for ``device``: ``setting`` when given, else on for CUDA devices only."""
    if setting is None:
        return torch.device(device).type == "cuda"
    if not isinstance(setting, bool):
        raise ValueError(  # noqa: TRY004
            f"compile must be true, false or null (null: on for CUDA devices), got {setting!r}")
    return setting


# the package's lru_cache'd helpers build constant tensors (joint ranges, gravity): tracing the wrapped function, as
# dynamo does, makes the same constant, which is what its notice is about; a recompile (a reset of another number of
# robots, a new schedule stream) traces again, after the first call's filter below has gone
warnings.filterwarnings("ignore", message="Dynamo detected a call to a `functools.lru_cache`")


RECOMPILE_LIMIT = 64
"""Dynamo's ``recompile_limit`` (8 by default) is raised to this when something is compiled. Compiled code is cached
per function, not per env: every env of another size in a process (a benchmark's sizes, an evaluation's envs) adds a
graph to each compiled function, and a reset function adds up to four per env (one robot, several, all of them, a
first draw stream); past the limit dynamo runs the function eagerly without telling the caller."""


class Fused:
    """``fn`` compiled with ``torch.compile(fullgraph=True, dynamic=dynamic)`` when ``enabled``, else ``fn`` itself.

    ``dynamic=True`` for functions whose batch size changes from call to call (a reset's robots). ``eager_first``
    (default: ``dynamic``): the first call runs eagerly, so that what the function makes on first use (an
    episode-schedule stream's counters) exists before it is traced and is not a guard that fails on the second
    call.

    Attributes:
        name: what the warning calls it.
        compiled: True while calls go through the compiled function (False when disabled or after a failure).
        error: the compile error that switched it to eager, if any.
    """

    def __init__(self, fn: Callable[..., Any], enabled: bool, name: str | None = None, dynamic: bool = False,
                 eager_first: bool | None = None):
        self.fn = fn
        self.name = name or getattr(fn, "__qualname__", repr(fn))
        self.compiled = bool(enabled)
        self.error: BaseException | None = None
        self._impl = torch.compile(fn, fullgraph=True, dynamic=dynamic) if enabled else fn
        self._first = bool(enabled)
        self._eager_first = bool(enabled and (dynamic if eager_first is None else eager_first))
        if enabled:
            dynamo_config = torch._dynamo.config
            dynamo_config.recompile_limit = max(dynamo_config.recompile_limit, RECOMPILE_LIMIT)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if not self._first:
            return self._impl(*args, **kwargs)
        if self._eager_first:
            self._eager_first = False
            return self.fn(*args, **kwargs)
        self._first = False
        try:
            return self._impl(*args, **kwargs)
        except Exception as err:  # any compile failure falls back to eager (module doc); others are re-raised
            if not _is_compile_error(err):
                raise
            self.compiled, self.error, self._impl = False, err, self.fn
            # the whole message: inductor's first line ("backend='inductor' raised:") names no cause
            warnings.warn(f"torch.compile of {self.name} failed, running it eagerly ({type(err).__name__}: {err})",
                          RuntimeWarning, stacklevel=2)
            return self.fn(*args, **kwargs)


class FusedCache:
    """One :class:`Fused` per function, all compiled or all eager: ``cache(fn, name, ...)`` returns ``fn``'s.

    An env keeps one (``LocomotionEnv.fused``) so that an event function's torch work, e.g. ``reset_robot``'s
    placement, is compiled where the env's scene compiles, once per env.
    """

    def __init__(self, enabled: bool):
        self.enabled = bool(enabled)
        self._fused: dict[Callable[..., Any], Fused] = {}

    def __call__(self, fn: Callable[..., Any], name: str | None = None, dynamic: bool = False,
                 eager_first: bool | None = None) -> Fused:
        if fn not in self._fused:
            self._fused[fn] = Fused(fn, self.enabled, name, dynamic=dynamic, eager_first=eager_first)
        return self._fused[fn]


class fused_method:  # lower case: a decorator, named like the built-in ones (property, staticmethod)
    """Decorator: the method, called through one :class:`Fused` per instance, made on first access.

    Args:
        name: what the compile-failure warning calls it.
        dynamic: ``Fused``'s (a batch size that changes from call to call).
        enabled: whether to compile, read from the instance once, on first access: a dotted attribute (``"compile"``,
            ``"env.compile"``) or a function of the instance (``lambda m: getattr(m.env, "compile", False)``).
        eager_first: ``Fused``'s (default: ``dynamic``; True: the instance's first call runs eagerly).

    The decorated function may be a ``staticmethod``. On an instance, the attribute is its ``Fused`` (kept in the
    instance's ``__dict__``, so later accesses are plain attribute reads); ``.fn`` is the method itself, eager.
    :meth:`renew` drops an instance's ``Fused``, so that the next access makes a new one.
    """

    def __init__(self, name: str, dynamic: bool = False, enabled: str | Callable[[Any], bool] = "compile",
                 eager_first: bool | None = None):
        self.name, self.dynamic, self.eager_first = name, dynamic, eager_first
        self._enabled = operator.attrgetter(enabled) if isinstance(enabled, str) else enabled
        self.fn: Any = None
        self.attr = ""

    def __call__(self, fn: Any) -> fused_method:
        if self.fn is not None:
            raise TypeError(f"fused_method({self.name!r}) decorates one function, got a second: {fn!r}")
        self.fn = fn
        return self

    def __set_name__(self, owner: type, attr: str) -> None:
        self.attr = attr

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        enabled = self._enabled(obj)
        if not isinstance(enabled, bool):
            raise TypeError(f"fused_method({self.name!r}): {type(obj).__name__}'s enabled attribute must be a bool, "
                            f"got {enabled!r}")
        fused = Fused(self.fn.__get__(obj, owner), enabled, self.name, dynamic=self.dynamic,
                      eager_first=self.eager_first)
        obj.__dict__[self.attr] = fused
        return fused

    def renew(self, obj: Any) -> None:
        """Drop ``obj``'s ``Fused`` (if made): the next access reads the setting again and makes a new one, first
        call and compile-failure fallback included."""
        obj.__dict__.pop(self.attr, None)


def _is_compile_error(err: BaseException) -> bool:
    """An error raised by dynamo or inductor (compile-time), not by the function's own code."""
    from torch._dynamo.exc import TorchDynamoException

    if isinstance(err, TorchDynamoException):
        return True
    module = type(err).__module__ or ""
    return module.startswith(("torch._dynamo", "torch._inductor", "torch._subclasses"))
