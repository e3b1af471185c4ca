"""What only the tests use, and the scripts behind some of the docs' figures.

Not installed with the product: ``rigs`` (simulated patches and the host on buses, children,
ports, waiting), the mutants runner (``python -m tests.support.mutants``), the pytest
benchmark file, and figure scripts each run from a checkout as
``python -m tests.support.NAME`` (its docstring says how).
"""
