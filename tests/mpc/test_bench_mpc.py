"""The MPC benchmark's report: table rows and speed-ups, docs sections replaced in place."""

from __future__ import annotations

from dls_quadruped.bench.mpc import SECTION, markdown_table, update_docs
from dls_quadruped.bench.mpc_builds import (
    BUILDS_SECTION,
    build_notes,
    builds_table,
    update_builds_docs,
)


def _results():
    row = {"device": "cpu", "N": 10, "M": 10000, "solves": 50}
    return [{**row, "kernel": "fast", "median_ms": 4.0, "p90_ms": 5.0, "min_ms": 3.5},
            {**row, "kernel": "cpp", "median_ms": 2.0, "p90_ms": 2.5, "min_ms": 1.5},
            {**row, "kernel": "reference", "median_ms": 40.0, "p90_ms": 44.0, "min_ms": 39.0}]


def test_table_speedup():
    table = markdown_table(_results())
    assert "| cpu | 10 | 10000 | 4.00 | 5.00 | 3.50 | 2.00 | 2.50 | 1.50 | 40.00 | 44.00 | 10.0x |" in table


def test_docs_section_replaced_and_others_kept(tmp_path):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(f"# Benchmarks\n\n## Env step time\n\nkeep me\n\n{SECTION}\n\nold numbers\n\n## Training\n\nkeep "
                   f"too\n")
    info = {"cpu": "AMD EPYC", "cpu_count": 2, "torch_threads": 2, "torch": "2.13", "load_avg_1_5_15": [1, 1, 1]}
    update_docs(markdown_table(_results()), info, _results(), doc)
    text = doc.read_text()
    assert "old numbers" not in text and "keep me" in text and "keep too" in text
    assert text.count(SECTION) == 1 and "speed-up 10.0x" in text
    assert text.index("## Env step time") < text.index(SECTION) < text.index("## Training")


def _build_rows():
    row = {"M": 10000, "N": 10, "solves": 50, "threads": 1}
    return [{**row, "variant": "native", "flags": "-O3 -march=native", "solve_median_ms": 3.0, "solve_p90_ms": 3.5,
             "kernel_median_ms": 1.0, "kernel_min_ms": 0.9},
            {**row, "variant": "x86-64-v3", "flags": "-O3 -march=x86-64-v3", "solve_median_ms": 4.0,
             "solve_p90_ms": 4.5, "kernel_median_ms": 2.0, "kernel_min_ms": 1.8},
            {**row, "variant": "scalar", "flags": "-O3 -fno-tree-vectorize", "solve_median_ms": 20.0,
             "solve_p90_ms": 21.0, "kernel_median_ms": 16.0, "kernel_min_ms": 15.0}]


def test_builds_table_ratios_and_peak_share():
    # v3: 4 / 20 = 0.20x solve, 2 / 16 = 0.12x kernel (0.125 -> "0.12"), 30 MFLOP / 2 ms = 15 GFLOP/s,
    # of a 100 GFLOP/s core = 15 %
    table = builds_table(_build_rows(), peak_core=100.0)
    assert ("| 1 | x86-64-v3 | `-O3 -march=x86-64-v3` | 4.00 | 4.50 | 2.00 | 1.80 | 0.20x | 0.12x | 15.0 | "
            "15.0 % |") in table
    assert ("| 1 | scalar | `-O3 -fno-tree-vectorize` | 20.00 | 21.00 | 16.00 | 15.00 | 1.00x | 1.00x | 1.9 | "
            "1.9 % |") in table
    two = [{**r, "threads": 2, "kernel_median_ms": r["kernel_median_ms"] / 2} for r in _build_rows()]
    assert "| 2 | native | `-O3 -march=native` | 3.00 | 3.50 | 0.50 | 0.90 | 0.15x | 0.06x | 60.0 | 30.0 % |" in \
        builds_table(_build_rows() + two, peak_core=100.0)  # ratios against the scalar build on as many threads
    notes = build_notes(_build_rows())
    assert len(notes) == 2 and "x86-64-v3: solve 4.00 ms = 0.20x the scalar build's 20.00 ms" in notes[1]
    assert "(speed-up 8.0x)" in notes[1]


def test_builds_section_goes_after_solve_time_then_is_replaced(tmp_path):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(f"# Benchmarks\n\n{SECTION}\n\nsolve numbers\n\n## Learning curve\n\nkeep\n")
    info = {"cpu": "AMD EPYC", "cpu_count": 2, "cpu_mhz": 2600.0, "peak_gflops_per_core": 83.2, "torch": "2.13",
            "simd_flags": ["avx2", "fma"], "compiler": "g++ 12", "load_avg_1_5_15": [1, 1, 1],
            "load_avg_end": [1, 1, 1]}
    update_builds_docs(_build_rows(), info, doc)
    update_builds_docs(_build_rows()[1:], info, doc)  # second run replaces the section in place
    text = doc.read_text()
    assert text.count(BUILDS_SECTION) == 1 and "| native |" not in text and "| x86-64-v3 |" in text
    assert text.index(SECTION) < text.index("solve numbers") < text.index(BUILDS_SECTION) < text.index("## Learning")
    assert "keep" in text and "2600 MHz x 32 FLOP/cycle" in text
