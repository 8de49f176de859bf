"""Benchmarks run by `make bench`; results go to results/bench/ and docs/benchmarks.md."""
