"""Benchmarks that run the skin as a deployment: several processes, buses and readers.

Each module is the code behind one ``skin bench`` target; the command modules in
``skin.commands`` parse the command line and print. ``bench.publish``: hosts publishing
on Zenoh and one reader (``skin bench publish``).
"""
