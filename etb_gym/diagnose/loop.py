"""Was a recording made in closed loop? A Granger-type test: does the recorded voltage react to the reading's
noise?

In open loop the voltage is chosen without looking at the readings, so its *innovation* (the part its own past
does not predict) is independent of the sensor noise. A controller acting on the readings passes their noise
into the voltage, whatever its filters (roll-off, derivative cut-off), gains or nonlinearity (saturation, a
sliding mode's switching, a relay): the innovation then depends on the latest readings.

    e[k]  = u[k] - (a_0 + sum_{j=1..P} a_j u[k-j])                     the voltage's innovation (least squares)
    w[k]  = y[k] - y[k-1]                                             the reading's increment (noise + motion)
    R^2   = share of e explained by w[k], ..., w[k-M], after projecting the lagged increments on the
            voltage's past (so what the plate does in response to earlier voltage, in open loop, cannot count)

Only lags l >= 0 (the voltage at or after the reading) enter: in open loop the plate answers the voltage
later, not earlier. The null is built from the recording itself: the increments shifted circularly by
random offsets break the alignment but keep both series' structure, and the statistic is the z-score of the
aligned R^2 against NULL_SHIFTS shifted ones. Two versions are scored and the larger z counts:

* *trimmed*: samples whose innovation exceeds TRIM x its robust spread (reference steps, stick-slip
  reactions, the saturation's edges) left out, so that a linear controller's small reaction to the noise
  is not drowned by them (a PID with a strong roll-off);
* *all samples*: a relay or bang-bang law reacts to the noise only through the instant it switches, which
  the trimmed version would drop.

Why not the earlier statistic (max |corr(d2V[k+l], d2y[k])| sqrt(n), l = 0..8): it relied on the noise
passing into the voltage within 8 samples at high frequency; a PID without friction compensation (its
roll-off filters the noise) read 1.4-3.3 against a threshold of 15, and a chirp read 17.7 (measured with
scripts/loop_detection.py, docs/diagnosis.md).
"""
from __future__ import annotations

import math

import numpy as np

AR_LAGS_S = 0.04        # P: the voltage's own past, in seconds (a controller's filters are forgotten within it)
AR_LAGS_MAX = 40
READING_LAGS = 10       # M: the voltage may react up to this many samples after the reading
NULL_SHIFTS = 200      # circular shifts of the null: 30 left the z-score of an open loop at 0.9-13.5 by the draw (below)
TRIM = 4.0
LOOP_Z = 8.0            # closed loop when the z-score exceeds this (measured: scripts/loop_detection.py)
MAX_SAMPLES = 200_000   # longer recordings are tested on their first MAX_SAMPLES samples
R2_ROUNDOFF = 1e-9      # a version whose aligned and shifted R^2 all lie below this explains nothing: its z-score
#                         would score round-off (an open-loop PRBS's trimmed samples: R^2 1e-28 against 3e-30 +- 2e-30,
#                         z 55; the figure moved with the BLAS/LAPACK build), so that version is not scored


def _lagmat(x: np.ndarray, lags, n0: int, n1: int) -> np.ndarray:
    return np.column_stack([x[n0 - lag:n1 - lag] for lag in lags])


def _mad(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def loop_evidence(voltage_V, angle_deg, dt_s: float, seed: int = 0) -> float:
    """The z-score of the voltage's dependence on the readings' latest increments (module docstring); about
    0 +- 1 in open loop, large in closed loop. 0.0 when the recording is too short or the voltage has no
    innovation at all (a constant or perfectly regular input)."""
    u = np.asarray(voltage_V, float)[:MAX_SAMPLES]
    y = np.asarray(angle_deg, float)[:MAX_SAMPLES]
    n = u.size
    p = int(min(AR_LAGS_MAX, max(10, round(AR_LAGS_S / dt_s)))) if dt_s > 0 and math.isfinite(dt_s) else 10
    m = READING_LAGS
    n0 = max(p, m) + 1
    if n - n0 < 5 * (p + m + 2) or not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        return 0.0
    scale = max(float(np.max(np.abs(u))), 1e-12)
    u = u / scale                                   # conditioning only: R^2 is scale-free
    dy = np.diff(y, prepend=y[0])
    A = np.column_stack([np.ones(n - n0), _lagmat(u, range(1, p + 1), n0, n)])
    coef, *_ = np.linalg.lstsq(A, u[n0:n], rcond=None)
    e = u[n0:n] - A @ coef
    s = _mad(e)
    rng = np.random.default_rng(seed)
    shifts = rng.integers(max(1, n // 10), max(2, n - n // 10), size=NULL_SHIFTS)
    best = 0.0
    for trim in (True, False):
        keep = (np.abs(e) <= TRIM * s) if (trim and s > 0) else np.ones(e.size, bool)
        ee, Ak = e[keep], A[keep]
        tot = float(ee @ ee)
        if keep.sum() < 5 * (p + m + 2) or tot <= 1e-24 * max(1.0, float(e @ e)) or tot <= 1e-20 * ee.size:
            continue
        Q, _ = np.linalg.qr(Ak)

        def r2(shift: int) -> float:
            Y = _lagmat(np.roll(dy, shift), range(0, m + 1), n0, n)[keep]
            Y = Y - Q @ (Q.T @ Y)                   # the increments' part the voltage's past does not explain
            c, *_ = np.linalg.lstsq(Y, ee, rcond=None)
            f = Y @ c
            return float(f @ f) / tot

        stat = r2(0)
        null = np.array([r2(int(k)) for k in shifts])
        sd = float(np.std(null))
        if sd > 0 and max(stat, float(np.max(null))) > R2_ROUNDOFF:
            best = max(best, (stat - float(np.mean(null))) / sd)
    return float(best)
