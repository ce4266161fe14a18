"""numba's thread pool for the parallel batch step: made to sleep, not spin, unless the user chose.

``ensure_thread_pool`` is called by ``Plant.step_batch`` before the first parallel batch step of the process;
importing etb_gym changes nothing. ``THREAD_POOL`` records what was done (also readable as
``etb_gym.integrate.THREAD_POOL``).
"""
from __future__ import annotations

import os

from .jit import HAVE_NUMBA


def configure_thread_pool() -> str:
    """Make numba's parallel batch step sleep, not spin, while it waits (:func:`ensure_thread_pool` calls it
    once, just before the first parallel batch step of the process; importing the package changes nothing).

    numba's default OpenMP layer busy-waits between parallel regions (libgomp's default spin). On a
    machine whose cores are shared (CI, several jobs, an RL learner stepping its envs) the spinning
    thread steals the core its partner needs: measured on a loaded 2-core machine, the 1024-plant
    batch step took 5.6-7.8 us of CPU per plant-step with spinning vs 1.4 us with sleeping
    (docs/speed.md). So, unless the user chose (``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT`` or
    ``NUMBA_THREADING_LAYER`` set), set ``OMP_WAIT_POLICY=PASSIVE`` before libgomp loads, or, if an
    OpenMP runtime is already loaded (torch imported first), pick numba's sleeping ``workqueue``
    layer. Returns what it did."""
    if not HAVE_NUMBA:
        return "no numba"
    env = os.environ
    if any(k in env for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER")):
        return "user setting kept"
    import numba

    try:
        with open("/proc/self/maps") as fh:
            gomp_loaded = "libgomp" in fh.read()
    except OSError:
        gomp_loaded = False
    if not gomp_loaded:
        env["OMP_WAIT_POLICY"] = "PASSIVE"
        return "OMP_WAIT_POLICY=PASSIVE"
    if numba.config.THREADING_LAYER == "default":
        try:
            numba.threading_layer()          # raises until a parallel region ran
            return "thread pool already running"
        except ValueError:
            numba.config.THREADING_LAYER = "workqueue"
            return "numba threading layer workqueue"
    return "user setting kept"


THREAD_POOL: str | None = None      # what configure_thread_pool did, once a parallel batch step was asked for


def ensure_thread_pool() -> str:
    """Configure the thread pool once per process (before numba's first parallel region loads libgomp)."""
    global THREAD_POOL
    if THREAD_POOL is None:
        THREAD_POOL = configure_thread_pool()
    return THREAD_POOL
