"""Benchmarks: the figures ``skin bench ...`` prints, each measured by a command anyone can
run. A benchmark may use every package (core, simulator, decoders, the CAN side)."""
