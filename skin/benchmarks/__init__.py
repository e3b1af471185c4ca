"""Benchmarks: how fast and how well canskin does its work, measured (``skin bench``).

The command line (``skin.commands.bench``) runs them and prints their figures; they import
the product packages and never the command line. ``decoders``, ``sim``, ``dataplane``,
``server``, ``contact``, ``robot``, ``realtime`` and ``publish`` are the benchmarks of
``skin bench``'s sub-commands; ``pairs``, ``judge`` and ``cross`` the scene pairs of
``skin bench cross``; ``paper`` the paper's figures side by side (``skin bench paper``);
``publish_fit`` where ``skin bench publish``'s CPU went and whether the machine carried the
shape, ``publish_sizing`` what any shape needs from such runs.
What only the tests use (rigs, children, ports, waiting) and the scripts behind some of the
docs' figures live in the checkout's ``tests/support``, not in the installed product.
"""
