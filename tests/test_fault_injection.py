"""SIGKILL at random moments of the benchmark, then --resume: the final CSV equals an uninterrupted run's,
rows only grow between kills, no half-written result. (More cycles: python scripts/fault_injection.py.)"""
import os
import random
import subprocess

import numpy as np
import pytest

from etb_gym.benchmark import load_trace, make_jobs, run_sweep
from etb_gym.faultinject import BENCH_GRID, benchmark_cmd, kill_resume_cycles, leftovers

pytestmark = pytest.mark.skipif(os.name != "posix", reason="SIGKILL needs POSIX")


def test_benchmark_survives_sigkill_and_resumes_identically(tmp_path):
    jobs = make_jobs(*BENCH_GRID, range(2))
    ref = tmp_path / "ref"
    run_sweep(jobs, ref, workers=1, progress=False)
    out = tmp_path / "killed"
    c = kill_resume_cycles(benchmark_cmd(out, seeds=2), out, n_kills=3, rng=random.Random(2), n_jobs=len(jobs),
                           jitter_s=0.1)   # warm caches: 8 rows can land within 0.6 s, the run ends unkilled
    assert c.kills >= 2 and max(c.rows_at_kill) > 0, c
    assert (out / "results.csv").read_bytes() == (ref / "results.csv").read_bytes(), \
        f"kills at {c.kill_times_s} s (rows then {c.rows_at_kill})"
    for j in jobs:
        a, b = load_trace(ref / "traces", j), load_trace(out / "traces", j)
        assert (a is None) == (b is None)
        if a is not None:
            assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)
    assert leftovers(out) == []


def test_benchmark_refuses_to_replace_results(tmp_path):
    out = tmp_path / "b"
    out.mkdir()
    (out / "results.csv").write_text("env,controller\n")
    r = subprocess.run(benchmark_cmd(out, resume=False), capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "already holds results.csv" in r.stderr and "--resume" in r.stderr
    assert (out / "results.csv").read_text() == "env,controller\n"
