"""LM trains with BLAS on one thread here too (see tests/decoder/conftest.py)."""

from tests.decoder.conftest import one_blas_thread

__all__ = ["one_blas_thread"]
