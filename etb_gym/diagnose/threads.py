"""BLAS on one thread during a diagnosis.

The diagnosis's linear algebra is small (normal equations of at most ~100 parameters, Gram matrices of a
10 000 x 100 Jacobian) and it already runs its fits in parallel processes (``--jobs``). A multi-threaded BLAS
gains nothing on such sizes and loses much on a shared machine: on a loaded 2-core machine a 100 x 100 solve
took 1.7 ms with OpenBLAS's two threads against 0.14 ms on one, a 10 000 x 100 Gram matrix 57 ms against
5.7 ms (``scripts/time_diagnosis.py`` profiles). So the diagnosis limits BLAS to one thread while it runs
(threadpoolctl; without it, nothing changes).
"""
from __future__ import annotations

import contextlib


def one_blas_thread():
    """A context in which BLAS/LAPACK calls run on one thread (a no-op without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:                     # optional: the limit only saves time
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")
