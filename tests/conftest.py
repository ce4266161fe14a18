import os
import time

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


def _pin_hypothesis_constants():
    """Hypothesis (>= 6.131) mixes numeric literals of every *local* module in sys.modules into its draws
    ("local constants"): our etb_gym modules and the generated steppers in the kernel cache. Which of them
    are loaded when a property test starts depends on the tests an xdist worker happened to run before it, so
    a ``derandomize=True`` test drew different examples in two CI runs of the same commit. An empty pool
    makes the draws a function of the test's source and hypothesis' version only (what derandomize promises);
    the strategies name their own edge values (exact 0, +-1, 1e-12). tests/test_property.py checks it."""
    try:
        from hypothesis.internal.conjecture import providers
    except ImportError:     # pragma: no cover - hypothesis is a dev dependency
        return
    if hasattr(providers, "_get_local_constants"):
        from hypothesis.internal.constants_ast import Constants

        pool = Constants()
        providers._get_local_constants = lambda: pool


_pin_hypothesis_constants()


@pytest.fixture
def still_plate_data():
    """A factory: ``make(current_A)`` gives the diagnosis' prepared data of one recording at 1 kHz whose plate stands
    at 40 deg while the current follows ``current_A`` (the voltage 1.25 ohm times it, 12 V supply): what the
    tests of a table over current (a supply drop's) fit on."""
    import numpy as np

    from etb_gym.diagnose.model import prepare
    from etb_gym.recordings import Recording

    def make(current_A):
        cur = np.asarray(current_A, float)
        t = np.arange(cur.size) * 1e-3
        rec = Recording(name="r.csv", t_s=t, voltage_V=1.25 * cur, angle_deg=np.full(t.size, 40.0), current_A=cur,
                        supply_V=None)
        return prepare([rec], 12.0)

    return make


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """``-n N`` without ``--dist``: work stealing instead of xdist's round-robin "load". Round-robin hands
    neighbouring tests -- the parametrizations of one test, mostly one plant composition each -- to different
    workers, so with a cold kernel cache both compiled the same stepper side by side (test_accuracy[2A] and
    test_convergence[2A]...). Work stealing gives each worker a contiguous half of the suite (neighbours stay
    together) and moves tests from the busier worker's tail when one runs dry. An explicit --dist is kept."""
    opt = config.option
    if getattr(opt, "numprocesses", None) and getattr(opt, "dist", None) == "no":
        opt.dist = "worksteal"


@pytest.fixture(scope="session")
def rich_duty():
    from etb_gym.excitation import rich_excitation

    return rich_excitation()


# ------------------------------------------------------------------------------ numba compile-time log
# ETB_GYM_COMPILE_LOG=path: every numba compilation (a cache miss) appends a tab-separated line to
# path.<xdist worker> -- test id, depth (0 = a compile the test's own call started, >0 = a callee compiled
# inside it), wall seconds, module.function, signature and the compiling thread's CPU seconds (what a loaded
# machine does not inflate). scripts/compile_log.py sums it per kernel and per test. Beside it: path.<worker>.need
# (every generated-stepper function a test first asked for in that process, loaded or compiled, with the wall
# seconds that took, lock waits included) and path.<worker>.cpu (the worker's CPU seconds).
_COMPILE_LOG = os.environ.get("ETB_GYM_COMPILE_LOG")
_current_test = ["<collection>"]

if _COMPILE_LOG:
    from numba.core import event as _event

    class _CompileLog(_event.Listener):
        def __init__(self, path):
            self.path, self.stack = path, []

        def on_start(self, ev):
            self.stack.append((time.perf_counter(), time.thread_time()))

        def on_end(self, ev):
            t0, c0 = self.stack.pop()
            dt, cpu = time.perf_counter() - t0, time.thread_time() - c0
            disp = ev.data["dispatcher"]
            fn = getattr(disp, "py_func", None)
            name = f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(disp))}"
            sig = ",".join(str(a) for a in ev.data["args"])
            with open(self.path, "a") as f:
                f.write(f"{_current_test[0]}\t{len(self.stack)}\t{dt:.3f}\t{name}\t{sig}\t{cpu:.3f}\n")

    _LOG_PATH = f"{_COMPILE_LOG}.{os.environ.get('PYTEST_XDIST_WORKER', 'main')}"
    _event.register("numba:compile", _CompileLog(_LOG_PATH))

    from etb_gym import kernel_cache as _kc

    _under_lock = _kc.compile_under_lock

    def _logged_under_lock(dispatcher, lock):
        """Also log every first request of a generated stepper's function in this process, loaded from the cache
        or compiled ("need" lines: what a test needs, warm cache or cold)."""
        _under_lock(dispatcher, lock)
        compile_ = dispatcher.compile

        def compile(sig):
            from numba.core import sigutils

            if tuple(sigutils.normalize_signature(sig)[0]) in dispatcher.overloads:
                return compile_(sig)
            t0 = time.perf_counter()
            try:
                return compile_(sig)
            finally:
                name = f"{dispatcher.py_func.__module__}.{dispatcher.py_func.__qualname__}"
                with open(_LOG_PATH + ".need", "a") as f:
                    f.write(f"{_current_test[0]}\t{time.perf_counter() - t0:.3f}\t{name}\n")

        dispatcher.compile = compile

    _kc.compile_under_lock = _logged_under_lock

    def pytest_sessionfinish(session):
        """The process's CPU seconds (with the subprocesses its tests waited for) beside the log: path.<worker>.cpu;
        on a loaded machine the busiest worker's CPU time estimates the suite's wall time on an idle one."""
        import resource

        cpu = sum(r.ru_utime + r.ru_stime for r in map(resource.getrusage,
                                                         (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)))
        with open(_LOG_PATH + ".cpu", "w") as f:
            f.write(f"{cpu:.1f}\n")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        _current_test[0] = item.nodeid
        yield
        _current_test[0] = "<between tests>"
