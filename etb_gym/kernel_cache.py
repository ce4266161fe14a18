"""Building the generated stepper (integrate.generate_source): the plain build for CPython, the numba build, and
numba's on-disk cache of it.

The fast build is written as a module to ``~/.cache/etb_gym/kernels`` (``ETB_GYM_CACHE`` moves it) whose name is a
digest of the source, the components' kernel modules, numba's version and integrate.STEPPER_REVISION, and
compiled with ``cache=True``; kernels defined where numba cannot cache from (``__main__``, closures) are
compiled in memory instead. ``borrow`` is the numba intrinsic that gives the stepper reference-count-free views.

Processes that share the cache (pytest-xdist workers, the diagnosis' worker pool) compile each generated module's
functions under a file lock (``etb_kernel_<digest>.lock``): the second process to need a function of that stepper
waits for the first one's compilation and then loads it from the cache instead of compiling it again beside it.
"""
from __future__ import annotations

import hashlib
import importlib.util
import contextlib
import inspect
import os
import sys
import threading
import time
from pathlib import Path

from .jit import HAVE_NUMBA, py_func


def kernel_digest(components) -> str:
    h = hashlib.sha256()
    for c in components:
        for fn in (c.kernel, c.advance, c.carry, c.edges, c.plausible, c.rate, c.damping):
            if fn is None:
                continue
            f = py_func(fn)
            try:
                h.update(inspect.getsource(inspect.getmodule(f)).encode())
            except (OSError, TypeError):
                h.update(repr(f).encode())
    return h.hexdigest()


def cache_dir() -> Path:
    d = os.environ.get("ETB_GYM_CACHE")
    return Path(d) if d else Path.home() / ".cache" / "etb_gym" / "kernels"


def is_jitted(fn) -> bool:
    return fn is not None and hasattr(fn, "py_func") and hasattr(fn, "signatures")


def importable(fn) -> bool:
    f = py_func(fn)
    mod = sys.modules.get(f.__module__)
    return mod is not None and f.__module__ != "__main__" and getattr(mod, f.__name__, None) is fn \
        and "<locals>" not in f.__qualname__


def identity(a, *readonly):
    return a


if HAVE_NUMBA:
    import numba as _nb
    from numba.extending import intrinsic as _intrinsic
    from numba.np.arrayobj import make_array as _make_array

    @_intrinsic
    def borrow(typingctx, arr, *readonly):
        """A view of array argument ``arr`` without a reference count (meminfo NULL); ``borrow(arr, True)`` types
        the view read-only.

        Slicing a numba array increments and decrements its reference count atomically; the stepper
        slices x, P and dx for every kernel call of every substep, and in the parallel batch step all
        rows share one count, so the threads fought over one cache line. Views of a borrowed array
        skip the count. Only ever borrow a *function argument* (its caller keeps it alive), never a
        local temporary.

        Read-only: numba compiles a function once per argument *type*, and a read-only array (the env's shared
        parameter vector) is another type than a writable one. The generated entry points hand P to
        control_step_dx as ``borrow(P, True)``, so control_step_dx, resolve and physical -- most of a
        composition's compile time -- compile once per composition, not once per caller's kind of P."""
        if not isinstance(arr, _nb.types.Array):
            return None
        out = arr.copy(readonly=True) if readonly else arr

        def codegen(context, builder, sig, args):
            src = _make_array(arr)(context, builder, value=args[0])
            dst = _make_array(out)(context, builder)
            for f in ("nitems", "itemsize", "data", "shape", "strides"):
                setattr(dst, f, getattr(src, f))
            dst.meminfo = context.get_constant_null(_nb.types.MemInfoPointer(arr.dtype))
            dst.parent = context.get_constant_null(_nb.types.pyobject)
            return dst._getvalue()

        return out(arr, _nb.types.StarArgTuple(readonly)), codegen
else:  # pragma: no cover
    borrow = identity


def build_plain(source: str, bound: dict) -> dict:
    """The generated module's namespace, run by CPython with the kernels' pure-Python functions."""
    ns = {name: py_func(f) for name, f in bound.items()}
    ns["prange"] = range
    ns["borrow"] = identity
    exec(compile(source, "<etb_gym plain stepper>", "exec"), ns)
    return ns


def build_fast(source: str, bound: dict, components, jit_options: dict, revision: str) -> dict:
    """The generated module's namespace compiled by numba: loaded from the on-disk cache when every bound
    kernel is importable by name, else compiled in memory."""
    import numba

    if all(importable(f) for f in bound.values()):
        try:
            return load_cached_module(source, bound, components, jit_options, revision)
        except OSError:
            pass
    ns = dict(bound)          # kernels defined somewhere numba cannot cache from: compile in memory
    ns["prange"] = numba.prange
    ns["borrow"] = borrow
    exec(compile(source, "<etb_gym fast stepper>", "exec"), ns)
    for name, opts in jit_options.items():
        ns[name] = numba.njit(**opts)(ns[name])
    return ns


def load_cached_module(source: str, bound: dict, components, jit_options: dict, revision: str) -> dict:
    """Write the decorated source as a module into cache_dir() (once per digest) and import it."""
    imports = [f"from {py_func(f).__module__} import {py_func(f).__name__} as {name}" for name, f in bound.items()]
    src = source.replace("import numpy as np\n", "import numpy as np\nfrom numba import njit, prange\n"
                         "from etb_gym.kernel_cache import borrow\n" + "\n".join(imports) + "\n", 1)
    for name, opts in jit_options.items():
        args = ", ".join(f"{k}={v!r}" for k, v in dict(opts, cache=True).items())
        src = src.replace(f"\ndef {name}(", f"\n@njit({args})\ndef {name}(", 1)
    import numba

    digest = hashlib.sha256((src + kernel_digest(components) + numba.__version__ + revision)
                            .encode()).hexdigest()[:20]
    return vars(import_cached_source(src, "etb_kernel", "k", digest, jit_options))


def import_cached_source(src: str, file_prefix: str, module_prefix: str, digest: str, entry_points):
    """Write ``src`` to ``cache_dir()/<file_prefix>_<digest>.py`` (once), import it as
    ``etb_gym_kernels.<module_prefix>_<digest>`` (once per process) and compile its ``entry_points`` under the
    digest's file lock (one process compiles, the others load numba's cache)."""
    d = cache_dir()
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"{file_prefix}_{digest}.py"
    if not path.exists():
        from .io import write_atomic
        write_atomic(path, src, fsync=False)
    modname = f"etb_gym_kernels.{module_prefix}_{digest}"
    if modname in sys.modules:
        return sys.modules[modname]
    spec = importlib.util.spec_from_file_location(modname, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[modname] = mod
    spec.loader.exec_module(mod)
    lock = d / f"{file_prefix}_{digest}.lock"
    for name in entry_points:
        compile_under_lock(getattr(mod, name), lock)
    return mod


LOCK_WAIT_S = 1800.0   # then compile anyway: a process that holds the lock this long is stuck, not compiling
_held: dict = {}       # lock path -> [thread lock, depth, fd]: re-entrant within a process (nested compiles)


@contextlib.contextmanager
def _file_lock(path: Path):
    """An exclusive lock on ``path`` shared by processes (flock) and re-entrant for the thread holding it."""
    entry = _held.setdefault(str(path), [threading.RLock(), 0, None])
    with entry[0]:
        if entry[1] == 0:
            entry[2] = _acquire(path)
        entry[1] += 1
        try:
            yield
        finally:
            entry[1] -= 1
            if entry[1] == 0 and entry[2] is not None:
                os.close(entry[2])          # closing the descriptor releases the flock
                entry[2] = None


def _acquire(path: Path):
    """An open descriptor holding an exclusive flock on path, or None where flock is unavailable (Windows, a
    file system without locks) or after LOCK_WAIT_S: the lock only saves duplicate work, never guards data."""
    try:
        import fcntl
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except (ImportError, OSError):
        return None
    deadline = time.monotonic() + LOCK_WAIT_S
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            if time.monotonic() > deadline:
                break
            time.sleep(0.05)
        except OSError:
            break
    os.close(fd)
    return None


def compile_under_lock(dispatcher, lock: Path) -> None:
    """Make ``dispatcher`` compile a new signature only while holding ``lock``. numba looks the signature up in
    its on-disk cache first (inside Dispatcher.compile), so a process that waited loads what the holder saved."""
    from numba.core import sigutils

    compile_ = dispatcher.compile

    def compile(sig):
        if tuple(sigutils.normalize_signature(sig)[0]) in dispatcher.overloads:
            return compile_(sig)            # compiled in this process already: no need to wait for the lock
        with _file_lock(lock):
            return compile_(sig)

    dispatcher.compile = compile
