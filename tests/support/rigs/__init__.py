"""Rigs: set-ups that drive simulated patches, the host and outside clients on buses, shared
by the tests and the scripts of tests/support."""
