"""The MPC benchmark's report: table rows and speed-up, docs section replaced in place."""

from __future__ import annotations

from dls_quadruped.bench.mpc import SECTION, markdown_table, update_docs


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
    doc.write_text(f"# Benchmarks\n\n## Env step time\n\nkeep me\n\n{SECTION}\n\nold numbers\n\n## Training\n\nkeep too\n")
    info = {"cpu": "AMD EPYC", "cpu_count": 2, "torch_threads": 2, "torch": "2.13", "load_avg_1_5_15": [1, 1, 1]}
    update_docs(markdown_table(_results()), info, _results(), doc)
    text = doc.read_text()
    assert "old numbers" not in text and "keep me" in text and "keep too" in text
    assert text.count(SECTION) == 1 and "speed-up 10.0x" in text
    assert text.index("## Env step time") < text.index(SECTION) < text.index("## Training")
