"""The soak bench (``bench/soak.py``): its fits by hand, and its verdict on two child processes, one that opens a
file every 50 ms and keeps it, one that holds still."""

from __future__ import annotations

import os
import sys

import pytest

from dls_quadruped.bench import soak

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="reads /proc (Linux)")
LIMITS = {"warmup_frac": 0.2, "max_rss_mib_per_h": 20.0, "max_fd_change": 2}


def test_flatness_by_hand():
    # 11 samples over 1 h; the first 2 (20 %) are the warm-up: memory 100 + 30 MiB per hour after it
    samples = [{"t_s": 360.0 * k, "rss_mib": 500.0 if k < 2 else 100.0 + 30.0 * k / 10, "fds": 40 if k < 2 else 12}
               for k in range(11)]
    fit = soak.flatness(samples, **LIMITS)
    assert fit["samples_fitted"] == 9 and fit["rss_mib_per_h"] == pytest.approx(30.0)
    assert fit["fd_change"] == 0 and fit["flat"] is False  # 30 MiB/h > 20
    fit = soak.flatness(samples, **{**LIMITS, "max_rss_mib_per_h": 31.0})
    assert fit["flat"] is True
    samples[-1]["fds"] = 15  # three more descriptors at the end
    assert soak.flatness(samples, **{**LIMITS, "max_rss_mib_per_h": 31.0})["fd_change"] == 3
    assert soak.flatness(samples[:3], **LIMITS)["samples_fitted"] == 3  # int(3 x 0.2) = 0 left out: judged
    assert soak.flatness(samples[:2], **LIMITS) == {"samples_fitted": 2, "flat": None}


def test_usage_of_this_process():
    with open("/proc/self/status") as fh:
        rss = next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:")) / 1024.0
    u = soak.usage(os.getpid())
    assert u["processes"] >= 1 and u["rss_mib"] >= 0.5 * rss and u["fds"] >= 3


def test_a_leaking_child_is_not_flat_and_a_still_one_is(tmp_path):
    leak = "import time\nkeep = []\nfor _ in range(80):\n    keep.append(open('/dev/null'))\n    time.sleep(0.05)\n"
    res = soak.soak([sys.executable, "-c", leak], minutes=4.0 / 60, every_s=0.25, out=tmp_path / "leak", limits=LIMITS)
    assert res["flat"] is False and res["fd_change"] > 10, res.get("fd_change")
    still = "import time\ntime.sleep(4)\n"
    res = soak.soak([sys.executable, "-c", still], minutes=3.0 / 60, every_s=0.25, out=tmp_path / "still",
                    limits={**LIMITS, "max_rss_mib_per_h": 1e4})  # a 3-s window: the fit of a few KiB is noisy
    assert res["flat"] is True and res["fd_change"] == 0
    assert (tmp_path / "still" / "soak.json").is_file()
    assert res["ended_by"] == "SIGTERM" and res["returncode"] == -15  # sleep(4) outlives the 3-s window


def test_the_closing_is_sampled_apart_and_not_judged(tmp_path):
    # still for the window; on SIGTERM it opens 20 files over 0.5 s (as a closing save and export might) and exits 0
    closer = ("import signal, sys, time\n"
              "def close(*_):\n"
              "    keep = [open('/dev/null') for _ in range(20)]\n"
              "    time.sleep(0.5)\n"
              "    sys.exit(0)\n"
              "signal.signal(signal.SIGTERM, close)\n"
              "time.sleep(30)\n")
    res = soak.soak([sys.executable, "-c", closer], minutes=2.0 / 60, every_s=0.25, out=tmp_path / "c",
                    limits={**LIMITS, "max_rss_mib_per_h": 1e4}, close_wait_s=10.0)
    assert res["ended_by"] == "SIGTERM" and res["returncode"] == 0
    assert res["flat"] is True and res["fd_change"] == 0  # the window held still
    assert len(res["closing"]) >= 1 and res["closing_fds_max"] >= res["fds_max"] + 20, res["closing"]
    assert all(s["t_s"] < res["closing"][0]["t_s"] for s in res["samples"])


def test_help_and_a_bad_value():
    import subprocess

    cmd = [sys.executable, "-m", "dls_quadruped.bench.soak"]
    ok = subprocess.run([*cmd, "--help"], capture_output=True, text=True, timeout=120, check=False)
    assert ok.returncode == 0 and "--max-rss-mib-per-h" in ok.stdout
    bad = subprocess.run([*cmd, "--minutes", "0"], capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and "--minutes" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
