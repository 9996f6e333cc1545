"""Benchmarks behind ``lcmesh bench ...``; results are summarized in BENCHMARKS.md."""
