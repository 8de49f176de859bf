"""Benchmarks run by `make bench`; results go to results/bench/ (`make bench-mpc UPDATE_DOCS=1` also rewrites the MPC
sections of docs/benchmarks.md)."""
