"""The one switch between compiled (numba) and plain-Python kernels.

Every physics equation in etb-gym is written once, as a scalar function decorated with :func:`kernel`.
With numba installed the decorator returns a compiled dispatcher whose ``.py_func`` is the untouched
Python function; without numba (or with ``ETB_GYM_DISABLE_JIT=1``) it returns an object exposing the
same ``.py_func`` so the plain path always exists. The plain path is what the tests compare the fast
path against.
"""
from __future__ import annotations

import os

try:  # numba is a core dependency, but the plain path must survive its absence
    import numba as _numba
except Exception:  # pragma: no cover - exercised only on machines without numba
    _numba = None

HAVE_NUMBA = _numba is not None and os.environ.get("ETB_GYM_DISABLE_JIT", "0") != "1"


class _PlainKernel:
    """Stand-in for a numba dispatcher when compilation is unavailable."""

    def __init__(self, fn):
        self.py_func = fn
        self.__name__ = fn.__name__
        self.__doc__ = fn.__doc__
        self.__wrapped__ = fn

    def __call__(self, *args):
        return self.py_func(*args)


def kernel(fn):
    """Mark a scalar physics function as a kernel (compiled with numba when available)."""
    if HAVE_NUMBA:
        return _numba.njit(cache=True, fastmath=False, error_model="numpy")(fn)
    return _PlainKernel(fn)


def py_func(fn):
    """The plain-Python function behind a kernel."""
    return getattr(fn, "py_func", fn)
