"""Metrics of one benchmark run and the results file (results.csv): the columns, reading, atomic writing.
The metrics are defined in etb_gym/benchmark.py's docstring."""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Mapping

import numpy as np

from etb_gym.bench_scenarios import TAIL_S, Scenario, step_band_deg
from etb_gym.bound import settling_index

from .io import write_atomic

CSV_COLUMNS = ("env", "controller", "scenario", "variant", "seed", "stable", "rise_time_s", "settling_time_s",
               "overshoot_pct", "steady_state_error_deg", "limit_cycle_deg", "iae_deg_s", "rms_error_deg",
               "control_effort", "peak_current_A", "duty_total_variation", "step_start_deg", "bound_s",
               "settling_ratio", "signals")
TEXT_COLUMNS = ("signals",)
KEY_COLUMNS = ("env", "controller", "scenario", "variant", "seed")


def metrics(trace: Mapping, sc: Scenario) -> dict:
    """The metrics of the module docstring for one trace."""
    t, phi, r, d, i = (np.asarray(trace[k], float) for k in ("t_s", "angle_deg", "reference_deg", "duty", "current_A"))
    dt = t[1] - t[0]
    k0 = int(round(sc.step_at_s / dt))
    w = slice(k0, None)
    e = r - phi
    tail = t >= t[-1] - TAIL_S + 1e-12
    out = {k: float("nan") for k in CSV_COLUMNS[5:] if k not in TEXT_COLUMNS}
    finite = bool(np.all(np.isfinite(phi)))
    out["iae_deg_s"] = float(np.sum(np.abs(e[w])) * dt)
    out["rms_error_deg"] = float(np.sqrt(np.mean(e[w] ** 2)))
    out["control_effort"] = float(np.sqrt(np.mean(d[w] ** 2)))
    out["peak_current_A"] = float(np.max(np.abs(i[w])))
    out["duty_total_variation"] = float(np.sum(np.abs(np.diff(d[k0:]))))
    out["steady_state_error_deg"] = float(np.mean(np.abs(e[tail])))
    out["limit_cycle_deg"] = float(0.5 * np.ptp(phi[tail]))
    if sc.kind == "step":
        a, b = sc.step_from_deg, sc.step_to_deg
        step = b - a
        y = (phi[w] - a) / step                              # normalized response, 0 -> 1
        tt = t[w] - t[k0]
        k10 = np.nonzero(y >= 0.1)[0]
        k90 = np.nonzero(y >= 0.9)[0]
        out["rise_time_s"] = float(tt[k90[0]] - tt[k10[0]]) if k10.size and k90.size else float("nan")
        band = step_band_deg(sc)
        out["step_start_deg"] = float(phi[k0])
        k = settling_index(phi[w], b, band, int(TAIL_S / dt))
        if abs(phi[k0] - a) > band:
            # the hold left the plate away from the step's start: no step response to measure (flagged NaN,
            # counted as a miss), where the old rule could report 0 ms for a plate already in the band
            out["settling_time_s"] = float("nan")
        else:
            out["settling_time_s"] = float("nan") if k is None else float(tt[k])
        out["overshoot_pct"] = float(max(0.0, (np.max(y) - 1.0) * 100.0))
        travel = abs(step)
    else:
        travel = float(np.ptp(r))
    out["stable"] = bool(finite and out["steady_state_error_deg"] < 2.0 + 0.05 * travel)
    return out


def read_results(path) -> list[dict]:
    p = Path(path)
    if not p.exists():
        return []
    with open(p, newline="") as fh:
        rows = list(csv.DictReader(fh))
    missing = [c for c in KEY_COLUMNS if rows and c not in rows[0]]
    if missing:
        raise ValueError(f"{p}: not a benchmark results file (missing columns {missing})")
    return [_parse_row(r) for r in rows]


def _parse_row(r):
    out = dict(r)
    out["seed"] = int(r["seed"])
    for c in CSV_COLUMNS[5:]:
        if c in TEXT_COLUMNS:
            out[c] = r.get(c) or ""
        elif c == "stable":
            out[c] = str(r[c]).lower() == "true"
        else:
            out[c] = float(r[c]) if r.get(c, "") not in ("", None) else float("nan")
    return out


def write_results(path, rows: list[dict]) -> None:
    """Write all rows atomically (tmp file + os.replace), sorted by key for a stable file."""
    rows = sorted(rows, key=lambda r: (r["env"], r["controller"], r["scenario"], r["variant"], int(r["seed"])))
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=CSV_COLUMNS)
    w.writeheader()
    for r in rows:
        w.writerow({c: _fmt(r[c]) for c in CSV_COLUMNS})
    write_atomic(path, buf.getvalue())


def _fmt(v):
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def row_key(r) -> tuple:
    return (r["env"], r["controller"], r["scenario"], r["variant"], str(r["seed"]))
