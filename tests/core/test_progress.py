"""``core/progress.py``: a tqdm bar on a terminal; quiet, periodic lines with an ETA elsewhere."""

from __future__ import annotations

import io

import pytest
from tqdm import tqdm

from dls_quadruped.core.progress import LineProgress, label, progress


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_lines_every_interval_with_eta_worked_out_by_hand():
    out, clock = io.StringIO(), FakeClock()
    bar = LineProgress(total=750, desc="episodes", unit="step", file=out, interval_s=15.0, clock=clock)
    for _ in range(100):  # 100 steps of 0.125 s (exact in binary): 12.5 s, no line yet
        clock.t += 0.125
        bar.update(1)
    assert out.getvalue() == ""
    for _ in range(20):  # 120 steps at 15 s: the first line; 630 left x 0.125 s = 78.75 s
        clock.t += 0.125
        bar.update(1)
    assert out.getvalue().splitlines() == ["[progress] episodes: 120/750 step (16 %), 00:15 elapsed, ETA 01:18"]
    bar.set_postfix_str("97 % alive")
    for _ in range(120):  # one more line at 30 s: 240 steps, 510 left x 0.125 s = 63.75 s
        clock.t += 0.125
        bar.update(1)
    bar.close()
    bar.close()  # idempotent
    assert out.getvalue().splitlines()[1:] == [
        "[progress] episodes: 240/750 step (32 %), 00:30 elapsed, ETA 01:03, 97 % alive",
        "[progress] episodes: 240/750 step (32 %), 00:30 elapsed, ETA 01:03, 97 % alive, done"]


def test_short_work_prints_nothing_and_unknown_totals_have_no_eta():
    out, clock = io.StringIO(), FakeClock()
    for _ in LineProgress(range(10), file=out, interval_s=15.0, clock=clock):
        clock.t += 1.0
    assert out.getvalue() == ""
    bar = LineProgress(desc="rounds", unit="round", file=out, interval_s=5.0, clock=clock)
    clock.t += 6.0
    bar.update(2)
    assert out.getvalue() == "[progress] rounds: 2 round, 00:06 elapsed\n"


def test_mode_follows_the_stream_and_the_environment(monkeypatch):
    monkeypatch.delenv("DLS_PROGRESS", raising=False)
    with progress(total=3, file=Terminal()) as bar:
        assert isinstance(bar, tqdm)
    with progress(total=3, file=io.StringIO()) as bar:
        assert isinstance(bar, LineProgress)
    monkeypatch.setenv("DLS_PROGRESS", "off")
    out = io.StringIO()
    bar = progress(total=3, file=out, interval_s=1e-9)
    bar.update(3)
    bar.close()
    assert out.getvalue() == "" and bar.n == 3
    monkeypatch.setenv("DLS_PROGRESS", "fancy")
    with pytest.raises(ValueError, match=r"DLS_PROGRESS must be one of \['bar', 'lines', 'off'\], got 'fancy'"):
        progress(total=3, file=out)
    monkeypatch.setenv("DLS_PROGRESS", "lines")
    monkeypatch.setenv("DLS_PROGRESS_INTERVAL_S", "0")
    with pytest.raises(ValueError, match="DLS_PROGRESS_INTERVAL_S must be a number of seconds > 0, got '0'"):
        progress(total=3, file=out)


def test_labels_prefix_the_description(monkeypatch):
    monkeypatch.setenv("DLS_PROGRESS", "lines")
    with label("eval survival"), label("speed 1.0"):
        bar = progress(total=1, desc="episodes", file=io.StringIO())
    assert bar.desc == "eval survival: speed 1.0: episodes"
    assert progress(total=1, desc="episodes", file=io.StringIO()).desc == "episodes"
