"""Benchmarks: `python -m benchmarks list | run NAME [--quick] | all | readme` (docs/benchmarks.md)."""
