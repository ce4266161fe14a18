#!/usr/bin/env python
"""SIGKILL fault injection of the benchmark: N random SIGKILL/--resume cycles, then the final CSV and traces are
compared with an uninterrupted run's. Prints one line per check; exit 0 when everything matches.

    python scripts/fault_injection.py --kills 20 --seeds 20 --seed 0
"""
from __future__ import annotations

import argparse
import random
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from etb_gym.benchmark import load_trace, make_jobs, read_results, run_sweep
from etb_gym.faultinject import BENCH_GRID, benchmark_cmd, kill_resume_cycles, leftovers


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kills", type=int, default=20, help="SIGKILL/resume cycles (default 20)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the kill times (default 0)")
    ap.add_argument("--seeds", type=int, default=20, help="benchmark seeds: 4 runs per seed (default 20: 80 runs)")
    ap.add_argument("--jitter", type=float, default=0.6,
                    help="kill a random 0..JITTER s after a random number of new rows reached the disk (default 0.6)")
    a = ap.parse_args(argv)
    jobs = make_jobs(*BENCH_GRID, range(a.seeds))
    with tempfile.TemporaryDirectory(prefix="etb_faults_") as tmp:
        ref, out = Path(tmp) / "ref", Path(tmp) / "killed"
        run_sweep(jobs, ref, workers=1, progress=False)
        t0 = time.monotonic()
        c = kill_resume_cycles(benchmark_cmd(out, seeds=a.seeds), out, a.kills, random.Random(a.seed), len(jobs),
                               jitter_s=a.jitter)
        same_csv = (out / "results.csv").read_bytes() == (ref / "results.csv").read_bytes()
        rows = read_results(out / "results.csv")
        keys = [(r["controller"], r["scenario"], r["variant"], r["seed"]) for r in rows]
        same_traces = True
        for j in jobs:
            x, y = load_trace(ref / "traces", j), load_trace(out / "traces", j)
            if (x is None) != (y is None) or (x is not None and not all(np.array_equal(x[k], y[k], equal_nan=True)
                                                                        for k in x)):
                same_traces = False
        left = leftovers(out)
    print(f"{c.kills} SIGKILLs (at {c.kill_times_s} s), {c.finished_early} runs finished before their kill, "
          f"rows on disk after each kill {c.rows_at_kill}; {time.monotonic() - t0:.0f} s")
    print(f"final results.csv identical to the uninterrupted run: {same_csv}; rows {len(rows)} of {len(jobs)}, "
          f"duplicates {len(keys) - len(set(keys))}; traces identical: {same_traces}; temporaries left: {len(left)}")
    return 0 if same_csv and same_traces and not left and len(rows) == len(jobs) else 1


if __name__ == "__main__":
    sys.exit(main())
