"""A function compiled in some runs and eager in others is written once (``core.compile.fused_method``, ``Fused``
around one function), not as a ``<name>_eager`` function beside a compiled wrapper built by hand; counted by
``tests/structure_stats.py``, the figures of docs/architecture.md "Structure, measured"."""

from __future__ import annotations

import structure_stats


def test_the_twin_count_finds_a_hand_written_pair():
    planted = ("class M:\n    def __init__(self, env):\n        self._compute = Fused(self._compute_eager, True)\n\n"
               "    def _compute_eager(self, dt):\n        return dt\n")
    assert structure_stats.twins_in("envs/managers/m.py", planted) == ["def _compute_eager(", "Fused("]
    # core/compile.py builds Fused itself; a fused_method or a FusedCache call is not a twin
    assert structure_stats.twins_in("core/compile.py", "x = Fused(fn, True)\n") == []
    written_once = '@fused_method("f")\ndef _f(self): ...\nc = FusedCache(True)\n'
    assert structure_stats.twins_in("envs/env.py", written_once) == []


def test_no_function_is_written_twice_for_compiled_and_eager_runs():
    figures = structure_stats.measure()
    assert figures["modules"] > 100
    assert figures["hand-written compiled/eager twins"] == 0
