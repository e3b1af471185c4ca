"""Rigs: set-ups that drive simulated patches, the host and outside clients on buses, shared
by the tests, the benchmarks and ``skin demo`` (``demo``: what the demo measures)."""
