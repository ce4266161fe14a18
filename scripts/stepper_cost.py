#!/usr/bin/env python
"""CPU (and wall) ns per plant-step of Plant.step_batch for models x substeps, serial and parallel, N plants:
this tree alone, or side by side with a git revision (fresh processes, alternating, medians).

    python scripts/stepper_cost.py --models 3B 2C 1A --substeps 5 10 20 --baseline 5dc542e --rounds 3
    python scripts/stepper_cost.py --baseline 5dc542e bd25a5d --rounds 5     # several revisions, one table
    python scripts/stepper_cost.py --worker 3B,2C 5,20 0.4 1024     # one round of this tree, JSON on stdout

Each plant starts at rest; every control period draws a new duty in [-1, 1] per plant (the plates hit the stops
often); every 64 periods the states go back to rest. The table of docs/speed.md ("Round 3") was made with it.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def worker(models, substeps, seconds, N) -> dict:
    import numpy as np

    from etb_gym import make_plant

    out = {}
    for m in models:
        for n in substeps:
            p = make_plant(m, substeps=n)
            rng = np.random.default_rng(0)
            X0 = np.tile(p.initial_state(), (N, 1))
            P, AUX = np.tile(p.P, (N, 1)), np.zeros((N, len(p.components)))
            V, t0, D = np.full(N, p.supply.voltage_V), np.zeros(N), rng.uniform(-1, 1, (64, N))
            for par in (False, True):
                X = X0.copy()
                for k in range(64):                      # compile / load, warm up
                    p.step_batch(X, D[k], V, P, t0, AUX, parallel=par)
                X[:] = X0
                reps, k = 0, 0
                w0, c0 = time.perf_counter(), time.process_time()
                while time.perf_counter() - w0 < seconds:
                    p.step_batch(X, D[k], V, P, t0, AUX, parallel=par)
                    k, reps = k + 1, reps + 1
                    if k == 64:
                        k = 0
                        X[:] = X0
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                out[f"{m}/{n}/{'parallel' if par else 'serial'}"] = {"wall_ns": 1e9 * wall / (reps * N),
                                                                      "cpu_ns": 1e9 * cpu / (reps * N)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--models", nargs="+", default=["3B", "2C", "1A"])
    ap.add_argument("--substeps", type=int, nargs="+", default=[5, 10, 20])
    ap.add_argument("--seconds", type=float, default=0.4, help="timed seconds per case and round (default 0.4)")
    ap.add_argument("--n", type=int, default=1024, help="plants per batch (default 1024)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    ap.add_argument("--baseline", metavar="REV", nargs="+", default=[],
                    help="git revision(s) to measure side by side with this tree (ratios: this tree / each)")
    ap.add_argument("--worker", nargs=4, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        ms, ns, sec, N = a.worker
        print(json.dumps(worker(ms.split(","), [int(v) for v in ns.split(",")], float(sec), int(N))))
        return 0
    if a.rounds < 1 or a.n < 2 or a.seconds <= 0 or any(n < 1 for n in a.substeps):
        ap.error("expected --rounds >= 1, --n >= 2, --seconds > 0 and --substeps >= 1")
    args = [",".join(a.models), ",".join(map(str, a.substeps)), str(a.seconds), str(a.n)]
    with tempfile.TemporaryDirectory(prefix="etb_stepper_cost_") as tmp:
        trees = {}
        if a.baseline:
            from etb_gym.speed_baseline import extract_revision

            for k, rev in enumerate(a.baseline):
                trees[rev] = str(extract_revision(rev, Path(tmp) / f"rev{k}")[1])
        trees["this tree"] = None
        res = {k: [] for k in trees}
        for r in range(a.rounds):
            for label, path in trees.items():
                env = dict(os.environ) if path is None else dict(os.environ, PYTHONPATH=path)
                out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", *args], env=env,
                                     cwd=tmp, capture_output=True, text=True)
                if out.returncode:
                    raise SystemExit(f"stepper_cost: the {label} run failed:\n{out.stderr[-3000:]}")
                res[label].append(json.loads(out.stdout.strip().splitlines()[-1]))
                print(f"round {r + 1}/{a.rounds} {label}: load {os.getloadavg()[0]:.2f}", file=sys.stderr, flush=True)
    labels, base = list(trees), list(trees)[:-1]
    print("| case | " + " | ".join(f"{k} CPU ns" for k in labels) + " |"
          + "".join(f" this tree / {k} |" for k in base))
    print("|---" * (len(labels) + 1 + len(base)) + "|")
    for key in res[labels[0]][0]:
        med = [statistics.median(run[key]["cpu_ns"] for run in res[k]) for k in labels]
        print(f"| {key} | " + " | ".join(f"{v:.0f}" for v in med) + " |"
              + "".join(f" {med[-1] / m:.2f} |" for m in med[:-1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
