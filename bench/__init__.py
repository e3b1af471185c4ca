"""Benchmarks that need the simulator and the decoders together: scene pairs for the
cross-scene checks, and the paper's figures side by side."""
