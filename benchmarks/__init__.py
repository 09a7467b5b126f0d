"""Benchmark and test infrastructure: the lossy-link forwarder (netsim) and before/after comparisons."""
