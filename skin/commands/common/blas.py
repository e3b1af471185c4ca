"""The BLAS thread pool of the commands that train: one thread."""

from __future__ import annotations


def limit_blas_threads() -> None:
    """LM's matrices are a few hundred wide: BLAS threads cost more than they give. SciPy
    may bring its own OpenBLAS, loaded on first import: import it before limiting, or its
    Cholesky keeps every core (10x slower per LM epoch on a busy 2-core machine)."""
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")
