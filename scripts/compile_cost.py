"""The compile CPU of one plant composition's stepper, measured in a fresh process with an empty kernel cache.

    nice -n 10 .venv/bin/python scripts/compile_cost.py 3B 1A 2C "3B+ShaftFluxLoss+SpringAsymmetry" --repeats 3

Each measurement runs in its own subprocess with its own empty ETB_GYM_CACHE and prints the compiling thread's CPU
seconds (what a loaded machine inflates least) for ``Plant.simulate`` (simulate, control_step_dx, resolve, physical;
resolve's own compile, which happens inside, also alone) and then for ``Plant.step`` (control_step). Run it from two checkouts side by
side (alternating) to compare two versions of the generated stepper; the medians are what to quote.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

_CHILD = r"""
import json, sys, time
import numpy as np
from etb_gym import make_plant
from etb_gym.components import effects as E
from numba.core import event
spent, stack = {}, []
class Log(event.Listener):
    def on_start(self, ev):
        stack.append(time.thread_time())
    def on_end(self, ev):
        name = getattr(ev.data["dispatcher"], "py_func", None)
        name = getattr(name, "__name__", "?")
        spent[name] = spent.get(name, 0.0) + time.thread_time() - stack.pop()
event.register("numba:compile", Log())
model, *effects = sys.argv[1].split("+")
p = make_plant(model, effects=[getattr(E, e)() for e in effects])
assert p.fast, "numba is needed to measure compile time"
d = np.full(5, 0.3)
c0 = time.thread_time()
p.simulate(d, angle_deg=20.0)
c1 = time.thread_time()
p.step(p.initial_state(), 0.3)
c2 = time.thread_time()
print(json.dumps({"simulate": c1 - c0, "step": c2 - c1, "resolve": spent.get("resolve", 0.0)}))
"""


def measure(composition: str) -> dict:
    """Compile CPU seconds of one composition in a fresh process with an empty kernel cache."""
    with tempfile.TemporaryDirectory(prefix="etb_compile_cost_") as cache:
        out = subprocess.run([sys.executable, "-c", _CHILD, composition], capture_output=True, text=True,
                             env=dict(os.environ, ETB_GYM_CACHE=cache), check=False)
    if out.returncode != 0:
        raise SystemExit(f"measuring {composition!r} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("compositions", nargs="+", help='a model, optionally with effect kinds: "3B+CoilHeating"')
    ap.add_argument("--repeats", type=int, default=1, help="measurements per composition (default 1)")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error(f"--repeats {a.repeats} is invalid: expected an integer >= 1")
    for comp in a.compositions:
        runs = [measure(comp) for _ in range(a.repeats)]
        sim = [r["simulate"] for r in runs]
        stp = [r["step"] for r in runs]
        res = [r["resolve"] for r in runs]
        print(f"{comp:40s} simulate {statistics.median(sim):6.2f} s CPU (of it resolve {statistics.median(res):5.2f})"
              f"  step {statistics.median(stp):5.2f}  (medians of {a.repeats}: simulate "
              f"{' '.join(f'{s:.2f}' for s in sim)}; resolve {' '.join(f'{s:.2f}' for s in res)})", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
