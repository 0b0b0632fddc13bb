"""Benchmarks: uwval against its peers, same input, same process run (python -m benchmarks)."""
