"""The compile CPU of one plant composition's stepper, measured in a fresh process with an empty kernel cache.

    nice -n 10 .venv/bin/python scripts/compile_cost.py 3B 1A 2C "3B+ShaftFluxLoss+SpringAsymmetry" --repeats 3

Each measurement runs in its own subprocess with its own empty ETB_GYM_CACHE and prints the compiling thread's CPU
seconds (what a loaded machine inflates least) for ``Plant.initial_state`` (rhs), ``Plant.simulate`` (simulate,
control_step_dx, resolve, physical; resolve's own compile, which happens inside, also alone), ``Plant.step``
(control_step), and with ``--batch`` ``Plant.step_batch`` on the calling thread (batch_step_serial,
control_step_group) and in parallel (batch_step), what a vector env compiles. Run it from two checkouts side by side
(alternating; ``PYTHONPATH=<other checkout>`` runs the other one's etb_gym) to compare two versions of the generated
stepper; the medians are what to quote.
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
c = [time.thread_time()]
x0 = p.initial_state(np.radians(20.0))
c.append(time.thread_time())
p.simulate(d, x0=x0)
c.append(time.thread_time())
p.step(x0.copy(), 0.3)
c.append(time.thread_time())
if "--batch" in sys.argv:
    N = 4
    P = np.tile(p.P, (N, 1))
    P.setflags(write=False)                 # as the vector env hands it
    for parallel in (False, True):
        p.step_batch(np.tile(x0, (N, 1)), np.full(N, 0.3), np.full(N, p.supply.voltage_V), P, np.zeros(N),
                     np.zeros((N, len(p.components))), parallel=parallel)
        c.append(time.thread_time())
names = ("initial_state", "simulate", "step", "serial", "parallel")
out = {k: c[j + 1] - c[j] for j, k in enumerate(names[:len(c) - 1])}
print(json.dumps(dict(out, resolve=spent.get("resolve", 0.0))))
"""


def measure(composition: str, batch: bool = False) -> dict:
    """Compile CPU seconds of one composition in a fresh process with an empty kernel cache."""
    with tempfile.TemporaryDirectory(prefix="etb_compile_cost_") as cache:
        out = subprocess.run([sys.executable, "-c", _CHILD, composition] + ["--batch"] * batch,
                             capture_output=True, text=True,
                             env=dict(os.environ, ETB_GYM_CACHE=cache), check=False)
    if out.returncode != 0:
        raise SystemExit(f"measuring {composition!r} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("compositions", nargs="+", help='a model, optionally with effect kinds: "3B+CoilHeating"')
    ap.add_argument("--repeats", type=int, default=1, help="measurements per composition (default 1)")
    ap.add_argument("--batch", action="store_true", help="also Plant.step_batch, serial and parallel (vector env)")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error(f"--repeats {a.repeats} is invalid: expected an integer >= 1")
    for comp in a.compositions:
        runs = [measure(comp, a.batch) for _ in range(a.repeats)]
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        total = [sum(v for k, v in r.items() if k != "resolve") for r in runs]
        print(f"{comp:40s} initial_state {med['initial_state']:5.2f}  simulate {med['simulate']:6.2f} s CPU (of it "
              f"resolve {med['resolve']:5.2f})  step {med['step']:5.2f}"
              + (f"  batch serial {med['serial']:5.2f} parallel {med['parallel']:5.2f}" if a.batch else "")
              + f"  total {statistics.median(total):6.2f}  (medians of {a.repeats}; totals "
              f"{' '.join(f'{s:.2f}' for s in total)})", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
