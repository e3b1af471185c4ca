"""Benchmarks and rigs: how fast and how well canskin does its work, measured.

Kept out of the product packages (they may use every package, as the ``skin`` command
does, and no product module imports them). ``skin bench decoders|cross|sim|dataplane|server``
runs ``decoders``, ``sim``, ``dataplane`` and ``server``; the other benchmarks are
scripts, each run as ``python -m bench.NAME`` (its docstring says how). ``bench.rigs``
holds the set-ups that tests and benchmarks share: simulated patches and the host on a
bus, recorders stopped mid-stream, independent canopen masters in processes of their own.
``bench.publish`` runs hosts publishing on Zenoh and one reader (``skin bench publish``),
``bench.publish_fit`` says where its CPU went and whether the machine carried the shape,
``bench.publish_sizing`` what any shape needs from such runs;
``bench.pairs``, ``bench.judge`` and ``bench.cross`` the scene pairs of ``skin bench cross``,
``bench.paper`` the paper's figures side by side (``skin bench paper``).
"""
