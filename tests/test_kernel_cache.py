"""The kernel cache's compile lock: a process that needs a generated stepper's function while another process
compiles one of that stepper's functions waits for it (then numba loads the saved result instead of compiling
it beside it); within one process the lock is re-entrant (a function's callees compile under the same lock)."""
import subprocess
import sys
import textwrap
import time

import pytest

from etb_gym.jit import HAVE_NUMBA
from etb_gym.kernel_cache import _file_lock, compile_under_lock

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="the lock is flock (POSIX); Windows compiles unlocked")
HOLD_S = 2.0
HOLDER = textwrap.dedent("""
    import fcntl, os, sys, time
    fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX)           # the lock kernel_cache takes (without importing numba: quick)
    print("held", flush=True)
    time.sleep(float(sys.argv[2]))
""")


def _hold(lock):
    """A process holding ``lock`` for HOLD_S seconds, once it says so."""
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(lock), str(HOLD_S)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


@pytest.mark.skipif(not HAVE_NUMBA, reason="compiles with numba")
def test_a_compile_waits_for_the_process_holding_the_lock(tmp_path):
    import numba

    lock = tmp_path / "etb_kernel_x.lock"

    @numba.njit
    def add_one(x):
        return x + 1

    compile_under_lock(add_one, lock)
    holder = _hold(lock)
    t0 = time.monotonic()
    assert add_one(1) == 2                       # a new signature: compiles once the holder lets go
    waited = time.monotonic() - t0
    holder.wait()
    assert waited > 0.5 * HOLD_S, waited
    holder = _hold(lock)
    t0 = time.monotonic()
    assert add_one(2) == 3                       # compiled in this process already: no wait
    assert time.monotonic() - t0 < 0.5 * HOLD_S
    holder.wait()
    with _file_lock(lock):                       # re-entrant: a compile under the held lock does not deadlock
        assert add_one(1.5) == 2.5


def test_the_lock_is_released_when_its_holder_is_done(tmp_path):
    lock = tmp_path / "etb_kernel_y.lock"
    with _file_lock(lock):
        with _file_lock(lock):
            pass
    holder = _hold(lock)                          # another process can take it now
    holder.wait()
    assert holder.returncode == 0
