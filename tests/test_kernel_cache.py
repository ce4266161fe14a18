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


@pytest.mark.skipif(not HAVE_NUMBA, reason="compiles with numba")
def test_a_read_only_borrow_compiles_the_callee_once_for_writable_and_read_only_arrays():
    """numba compiles a function once per argument type, and a read-only array is another type than a writable
    one: the env's shared parameter vector (read-only) and Plant.simulate's (writable) compiled control_step_dx,
    resolve and physical twice per composition. The generated entry points hand P on as borrow(P, True)."""
    import numba
    import numpy as np

    from etb_gym.kernel_cache import borrow, identity

    @numba.njit
    def callee(x, P):
        x[0] += P[1]

    @numba.njit
    def caller(x, P):
        callee(borrow(x), borrow(P, True))
        return x[0]

    x, P = np.zeros(2), np.arange(3.0)
    ro = P.copy()
    ro.setflags(write=False)
    assert caller(x, P) == 1.0 and caller(x, ro) == 2.0
    assert len(caller.signatures) == 2                      # the entry point: once per caller's kind of P
    (sig,) = callee.signatures                              # the callee: once
    assert sig[0].mutable and not sig[1].mutable
    assert identity(P, True) is P                           # the plain build's borrow takes the flag too


def test_the_generated_control_step_inlines_one_substep_and_hands_on_a_read_only_P():
    """control_step_dx steps through one loop over the intervals of constant voltage: ``step`` (inlined with its
    substep) appears once, not once per PWM mode and interval (3 copies compiled ~2x slower). Every call of
    control_step_dx passes a read-only P (see the test above) and control_step_group gets no literal index."""
    import re

    from etb_gym import make_plant

    src = make_plant("1A").engine.source
    body = src.split("def control_step_dx(")[1].split("\ndef ")[0]
    assert len(re.findall(r"\bstep\(", body)) == 1, body
    calls = [src[m.end():].split(",")[3].strip() for m in re.finditer(r"(?<!def )\bcontrol_step_dx\(", src)]
    assert sorted(calls) == ["Pb[b]"] * 2 + ["Pr"] * 2 + ["borrow(P"], calls    # batch steps (one prange each), simulate, observe, control_step
    assert src.count("borrow(P, True)") == 5
    assert "Pb = borrow(P, True)" in src and "Pb = borrow(P)" not in src
    groups = [src[m.end():].split(",")[8].strip() for m in re.finditer(r"(?<!def )\bcontrol_step_group\(", src)]
    assert groups == ["j * GROUP", "j * GROUP"], groups
