"""Benchmarks for focas-edge: fleet scale, round trips per poll cycle, codec throughput, write latency.

Run with ``make bench`` or ``python -m bench [name ...] [--quick]``; results are printed as tables and
written as JSON under bench/results/. docs/performance.md records the numbers and the commands.
"""
