"""Experiments, comparisons, reports, tuning, figures and benchmarks."""
