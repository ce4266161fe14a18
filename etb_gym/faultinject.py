"""SIGKILL fault injection for long jobs: run a command, kill it (SIGKILL: no cleanup, no finally) at random
moments, resume it, and compare what it leaves with an uninterrupted run.

    python scripts/fault_injection.py --kills 20        # the benchmark, 20 random SIGKILL/resume cycles

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


def kill_resume_cycles(cmd: list, out: Path, n_kills: int, rng: random.Random, window_s: tuple = (1.0, 8.0),
                       results: str = "results.csv", env: dict | None = None, timeout_s: float = 600.0) -> Cycles:
    """Run ``cmd`` (which must resume from ``out``) ``n_kills`` times, each killed with SIGKILL after a random
    time in ``window_s``; after each kill check that ``out/results`` is a complete CSV whose rows only grow.
    Then run it once more to completion. Returns what happened; raises AssertionError on a broken file."""
    if not POSIX:
        raise RuntimeError("SIGKILL fault injection needs a POSIX system")
    c = Cycles()
    seen = 0
    for _ in range(n_kills):
        p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, start_new_session=True)
        t = rng.uniform(*window_s)
        try:
            p.wait(timeout=t)
            c.finished_early += 1
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)          # the whole group: worker processes die too
            p.wait()
            c.kills += 1
            c.kill_times_s.append(round(t, 2))
        err = p.stderr.read().decode(errors="replace")
        p.stderr.close()
        if p.returncode not in (0, -signal.SIGKILL):
            raise AssertionError(f"{' '.join(map(str, cmd))} failed (exit {p.returncode}):\n{err}")
        rows = _rows(out / results)
        widths = {len(r) for r in rows}
        assert len(widths) <= 1, f"{out / results}: rows of different lengths after a kill (half-written)"
        assert len(rows) >= seen, f"{out / results}: rows were lost ({seen} -> {len(rows)})"
        seen = len(rows)
        c.rows_at_kill.append(max(len(rows) - 1, 0))
    t0 = time.monotonic()
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, timeout=timeout_s)
    if r.returncode != 0:
        raise AssertionError(f"the final resume failed (exit {r.returncode}) after {time.monotonic() - t0:.0f} s:\n"
                             f"{r.stderr.decode(errors='replace')}")
    return c


def leftovers(out: Path) -> list:
    """Temporary files a killed writer left behind (hidden ``.NAME.xxxx.tmp``; never a result's name)."""
    return sorted(p for p in Path(out).rglob("*") if is_temporary(p))


def benchmark_cmd(out: Path, resume: bool = True, extra: tuple = ()) -> list:
    root = Path(__file__).resolve().parents[1]
    cmd = [sys.executable, str(root / "scripts" / "benchmark.py"), "--controller", "pid", "--scenario", "small_step_40",
           "--scenario", "step_10_80", "--variant", "nominal", "--variant", "friction_+50", "--seeds", "2",
           "--workers", "1", "--no-plots", "--quiet", "--out", str(out), *extra]
    return cmd + (["--resume"] if resume else [])
