"""Thread limits of the estimation: BLAS/LAPACK on one thread while solvers run."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

__all__ = ["single_threaded_blas"]

_blas_lock = threading.Lock()
_blas_users = 0


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Limit BLAS/LAPACK to one thread while the solver runs.

    The trust-region solver takes an SVD of a tall, thin Jacobian (samples x parameters)
    at every step; threaded LAPACK is no faster on such shapes and, on a loaded machine,
    measured 30-70 times slower (0.3 s instead of 0.005 s for 5600 x 23 on 2 cores).

    Re-entrant, and shared by threads: the limit is process-wide (threadpoolctl lets one
    thread at a time set it), so the first user sets it, in its thread, for as long as it
    is inside; users on other threads meanwhile run under it. Callers that run refinements
    on threads enter it first, around the threads (as
    :func:`~piezocomp.identification.estimation.chain.estimate` does).
    """
    global _blas_users
    from threadpoolctl import threadpool_limits

    with _blas_lock:
        first = _blas_users == 0
        _blas_users += 1
    try:
        if first:
            with threadpool_limits(limits=1, user_api="blas"):
                yield
        else:
            yield
    finally:
        with _blas_lock:
            _blas_users -= 1
