"""The PPO benchmark's summary (bench/ppo_update.py): medians and samples/s worked out by hand."""

from __future__ import annotations

import pytest

from dls_quadruped.bench.ppo_update import bench_size, markdown, summarise


def test_summary_medians_and_samples_per_second():
    its = [{"collection_s": c, "learning_s": u, "samples": 6144} for c, u in ((2.0, 6.0), (1.0, 3.0), (4.0, 2.0))]
    s = summarise(its)
    assert s["collection_s"] == 2.0 and s["update_s"] == 3.0  # medians of each part on its own
    assert s["total_s"] == 5.0
    assert s["collection_samples_per_s"] == pytest.approx(3072.0)
    assert s["update_samples_per_s"] == pytest.approx(2048.0)
    assert s["samples_per_s"] == pytest.approx(6144.0 / 5.0)
    assert s["update_share"] == pytest.approx(0.6)


def test_markdown_row_per_size_and_variant():
    s = {**summarise([{"collection_s": 1.0, "learning_s": 3.0, "samples": 100}]),
         "update_vs_stock": 1.5, "end_to_end_vs_stock": 1.25}
    table = markdown({"sizes": [{"num_envs": 256, "summary": {"stock": s, "fast": s}}]})
    rows = table.splitlines()
    assert len(rows) == 4 and rows[2].startswith("| 256 | stock | 1.00 | 3.00 | 75% | 100 | 33 | 25 | 1.50x | 1.25x |")


@pytest.mark.parametrize("variants", [("fast", "fast_bf16"), ("stock", "fast_fp16")])
def test_variants_need_stock_and_known_names(variants):
    with pytest.raises(ValueError, match="need 'stock' and only"):
        bench_size("base", 8, 1, 1, variants)
