"""SIGKILL fault injection for long jobs: run a command, kill it (SIGKILL: no cleanup, no finally) at random
moments, resume it, and compare what it leaves with an uninterrupted run.

    python scripts/fault_injection.py --kills 20 --seeds 20  # the benchmark, 20 random SIGKILL/resume cycles

Used by tests/test_fault_injection.py (a few cycles) and scripts/fault_injection.py (many).
"""
from __future__ import annotations

import csv
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .io import is_temporary

POSIX = os.name == "posix"


@dataclass
class Cycles:
    kills: int = 0               # processes killed before they finished
    finished_early: int = 0      # runs that completed before their kill time came
    kill_times_s: list = field(default_factory=list)
    rows_at_kill: list = field(default_factory=list)


def _rows(csv_path: Path) -> list:
    if not csv_path.exists():
        return []
    with open(csv_path, newline="") as fh:
        return list(csv.reader(fh))


def _wait_rows(p: subprocess.Popen, csv_path: Path, target: int, deadline: float) -> bool:
    """Poll until ``csv_path`` holds ``target`` data rows; False if the process ended first."""
    while time.monotonic() < deadline:
        if p.poll() is not None:
            return False
        if max(len(_rows(csv_path)) - 1, 0) >= target:
            return True
        time.sleep(0.02)
    return p.poll() is None


def kill_resume_cycles(cmd: list, out: Path, n_kills: int, rng: random.Random, n_jobs: int,
                       jitter_s: float = 0.6, max_rows_per_cycle: int = 3, results: str = "results.csv",
                       env: dict | None = None,
                       timeout_s: float = 600.0) -> Cycles:
    """Run ``cmd`` (which must resume from ``out``) ``n_kills`` times; each run is killed with SIGKILL (the whole
    process group, no cleanup) at a random point of the sweep: once a random number (0 .. ``max_rows_per_cycle``
    - 1) of new rows is on disk,
    after a further random 0..``jitter_s`` s (so kills land inside jobs and inside writes). After each kill,
    ``out/results`` must be a complete CSV whose rows only grow. Then the command runs once more to completion.
    Returns what happened; raises AssertionError on a broken file."""
    if not POSIX:
        raise RuntimeError("SIGKILL fault injection needs a POSIX system")
    c = Cycles()
    csv_path = out / results
    seen = 0
    for _ in range(n_kills):
        remaining = n_jobs - seen
        if remaining <= 0:
            break
        target = seen + rng.randrange(min(remaining, max_rows_per_cycle))
        p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, start_new_session=True)
        t0 = time.monotonic()
        alive = _wait_rows(p, csv_path, target, t0 + timeout_s)
        if alive:
            try:
                p.wait(timeout=rng.uniform(0.0, jitter_s))
            except subprocess.TimeoutExpired:
                pass
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)          # the whole group: worker processes die too
            p.wait()
            c.kills += 1
            c.kill_times_s.append(round(time.monotonic() - t0, 2))
        else:
            c.finished_early += 1
        err = p.stderr.read().decode(errors="replace")
        p.stderr.close()
        if p.returncode not in (0, -signal.SIGKILL):
            raise AssertionError(f"{' '.join(map(str, cmd))} failed (exit {p.returncode}):\n{err}")
        rows = _rows(csv_path)
        widths = {len(r) for r in rows}
        assert len(widths) <= 1, f"{csv_path}: rows of different lengths after a kill (half-written)"
        n_rows = max(len(rows) - 1, 0)
        assert n_rows >= seen, f"{csv_path}: rows were lost ({seen} -> {n_rows})"
        seen = n_rows
        c.rows_at_kill.append(n_rows)
    t0 = time.monotonic()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, timeout=timeout_s)
    if r.returncode != 0:
        raise AssertionError(f"the final resume failed (exit {r.returncode}) after {time.monotonic() - t0:.0f} s:\n"
                             f"{r.stderr.decode(errors='replace')}")
    return c


def leftovers(out: Path) -> list:
    """Temporary files a killed writer left behind (hidden ``.NAME.xxxx.tmp``; never a result's name)."""
    return sorted(p for p in Path(out).rglob("*") if is_temporary(p))


BENCH_GRID = (["pid"], ["small_step_40", "step_10_80"], ["nominal", "friction_+50"])


def benchmark_cmd(out: Path, seeds: int = 2, resume: bool = True, extra: tuple = ()) -> list:
    """The benchmark script on BENCH_GRID x ``seeds`` seeds, one worker, into ``out``."""
    root = Path(__file__).resolve().parents[1]
    (ctrl,), (s1, s2), (v1, v2) = BENCH_GRID
    cmd = [sys.executable, str(root / "scripts" / "benchmark.py"), "--controller", ctrl, "--scenario", s1,
           "--scenario", s2, "--variant", v1, "--variant", v2, "--seeds", str(seeds),
           "--workers", "1", "--no-plots", "--quiet", "--out", str(out), *extra]
    return cmd + (["--resume"] if resume else [])
