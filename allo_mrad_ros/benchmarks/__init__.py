"""Benchmarks that print figures and write them to ``reports/`` (run by ``make bench-*``)."""
