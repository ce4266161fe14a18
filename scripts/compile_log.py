"""Summarise the numba compile-time log the test suite writes with ETB_GYM_COMPILE_LOG=path (tests/conftest.py).

    ETB_GYM_CACHE=/tmp/cold ETB_GYM_COMPILE_LOG=/tmp/cold/compile.log .venv/bin/python -m pytest -q -n 2
    .venv/bin/python scripts/compile_log.py /tmp/cold/compile.log.* --cache /tmp/cold

Prints the compile seconds (wall, or with --cpu the compiling thread's CPU) per test (top-level compiles only: a callee compiled inside its caller is part of the
caller's time), per function and the number of distinct generated steppers (etb_gym_kernels modules) compiled;
with --cache (the run's ETB_GYM_CACHE) each stepper is named by its plant composition, with --tests followed by the
tests that needed it.
"""
from __future__ import annotations

import argparse
import collections
import sys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", help="the per-worker log files (path.gw0, path.gw1, ...)")
    ap.add_argument("--top", type=int, default=25, help="rows per table (default 25)")
    ap.add_argument("--cpu", action="store_true", help="sum the compiling thread's CPU seconds, not wall seconds")
    ap.add_argument("--cache", default=None, help="the run's ETB_GYM_CACHE: name each stepper by its composition")
    ap.add_argument("--tests", action="store_true",
                    help="under each stepper, the tests that needed it (from the path.<worker>.need files)")
    a = ap.parse_args(argv)
    per_test, per_fn, per_fn_n, kernels = (collections.Counter(), collections.Counter(), collections.Counter(),
                                           collections.Counter())
    total = 0.0
    a.logs = [p for p in a.logs if not p.endswith((".cpu", ".need"))]
    for path in a.logs:
        try:
            lines = open(path).read().splitlines()
        except OSError as e:
            print(f"cannot read the log {path}: {e.strerror}", file=sys.stderr)
            return 2
        for ln in lines:
            test, depth, sec, name, *rest = ln.split("\t")
            sec = float(rest[1]) if len(rest) > 1 and a.cpu else float(sec)
            if depth == "0":
                total += sec
                per_test[test] += sec
                per_fn[name] += sec
                per_fn_n[name] += 1
                if name.startswith("etb_gym_kernels."):
                    kernels[name.split(".")[1]] += sec
    print(f"top-level compile time {total:.1f} s (summed over workers); {len(kernels)} generated steppers "
          f"compiled, {sum(kernels.values()):.1f} s of it")
    for path in a.logs:
        try:
            print(f"CPU {open(path + '.cpu').read().strip()} s in {path}")
        except OSError:
            pass
    print("\nper test:")
    for t, s in per_test.most_common(a.top):
        print(f"  {s:7.1f} s  {t}")
    print("\nper function (compiles):")
    for t, s in per_fn.most_common(a.top):
        print(f"  {s:7.1f} s  ({per_fn_n[t]:3d})  {t}")
    users = needed_by(a.logs) if a.tests else {}
    print("\nper generated stepper:")
    for t, s in kernels.most_common(a.top):
        print(f"  {s:7.1f} s  {t}  {composition(a.cache, t)}")
        for test in sorted(users.get(t, ())):
            print(f"               {test}")
    return 0


def needed_by(logs) -> dict:
    """Generated stepper module (k_<digest>) -> the tests that first asked for one of its functions in their
    process (loaded from the cache or compiled), from the ``.need`` files beside the logs."""
    users = collections.defaultdict(set)
    for path in logs:
        try:
            lines = open(path + ".need").read().splitlines()
        except OSError:
            continue
        for ln in lines:
            test, _, name = ln.split("\t")
            if name.startswith("etb_gym_kernels."):
                users[name.split(".")[1]].add(test)
    return users


def composition(cache, module: str) -> str:
    """The components of generated stepper ``module`` (k_<digest>), from its file's first line in ``cache``."""
    if not cache:
        return ""
    try:
        with open(f"{cache}/etb_kernel_{module[2:]}.py") as f:
            return f.readline().split("for: ", 1)[-1].strip()
    except OSError:
        return "(not in the cache folder)"


if __name__ == "__main__":
    raise SystemExit(main())
