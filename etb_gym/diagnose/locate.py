"""Where the model and the recordings disagree: windows in time, operating regimes, and residual tests.

    moving RMS      m(t) = sqrt(mean of r^2 over a window W around t);   significant where
                    m > K * sqrt(sigma_n^2 + tol^2)  (sigma_n: the noise floor, measurement.noise_floor;
                    tol(t): moving RMS of the model's own integration error, the difference between the
                    calibrated model at its substeps and at twice as many); windows closer than GAP_S merge,
                    windows shorter than MIN_WINDOW_S are dropped
    regimes         RMS and mean of the residual inside angle bands, near limp-home and the stops, by
                    direction and size of the velocity, by current level and by third of the recording;
                    significant where the RMS exceeds REGIME_K * sigma_n over at least REGIME_MIN_S
    whiteness       Ljung-Box Q = n(n+2) sum_{k<=L} rho_k^2/(n-k) against chi^2(L)   (as MATLAB resid)
    input xcorr     max |rho_ru(tau)|, tau = 0..50 samples, against the 99 % bound 2.58/sqrt(n)
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import stats

from .measurement import smooth

WINDOW_S = 0.1
K_WINDOW = 3.0
GAP_S = 0.05
MIN_WINDOW_S = 0.03
REGIME_K = 2.0
REGIME_MIN_S = 0.1


@dataclasses.dataclass
class Regime:
    name: str
    mask: np.ndarray


def regimes(rec, limp_home_deg: float, current_A=None, stops_deg=(0.0, 90.0)) -> list:
    """Boolean masks of the operating regimes of one recording (from the measured angle)."""
    y = rec.angle_deg
    dt = rec.dt_s
    v = np.gradient(smooth(y, 15), dt)                    # deg/s
    moving = np.abs(v) > 20.0
    out = []
    top = max(90.0, float(stops_deg[1]))
    for lo, hi in ((0, 10), (10, 30), (30, 60), (60, 90)):
        last = hi == 90
        lo_m = min(lo, float(stops_deg[0]) - 1.0) if lo == 0 else lo      # the bands cover the whole stroke
        out.append(Regime(f"angle {lo}-{top if last else hi:.0f} deg",
                          (y >= lo_m) & (y < (top + 1.0 if last else hi))))
    out.append(Regime("near limp-home (+-2 deg)", np.abs(y - limp_home_deg) < 2.0))
    out.append(Regime(f"near the closed stop (< {stops_deg[0] + 1.5:.1f} deg)", y < stops_deg[0] + 1.5))
    out.append(Regime(f"near the open stop (> {stops_deg[1] - 2.0:.1f} deg)", y > stops_deg[1] - 2.0))
    out.append(Regime("opening", v > 20.0))
    out.append(Regime("closing", v < -20.0))
    out.append(Regime("at rest", ~moving))
    out.append(Regime("fast (> 300 deg/s)", np.abs(v) > 300.0))
    if current_A is not None:           # levels relative to the recording's own peak current (any nameplate)
        a = np.abs(np.asarray(current_A, float))
        fin = a[np.isfinite(a)]
        peak = float(np.percentile(fin, 99)) if fin.size else 0.0
        lo_a, hi_a = (0.1 * peak, 0.3 * peak) if peak > 0 else (1.0, 3.0)
        out.append(Regime(f"low current (< {lo_a:.2g} A)", a < lo_a))
        out.append(Regime(f"high current (> {hi_a:.2g} A)", a > hi_a))
    n = y.size
    for k, nm in enumerate(("early in the recording", "middle of the recording", "late in the recording")):
        m = np.zeros(n, bool)
        m[k * n // 3:(k + 1) * n // 3] = True
        out.append(Regime(nm, m))
    return out


def moving_rms(r: np.ndarray, n: int) -> np.ndarray:
    return np.sqrt(smooth(r ** 2, n))


def windows(t_s: np.ndarray, r_deg: np.ndarray, sigma_deg: float, tol_deg=None, window_s: float = WINDOW_S,
            k: float = K_WINDOW) -> list:
    """Time windows [t0, t1] where the moving RMS of the residual exceeds k * sqrt(sigma^2 + tol^2)
    (tol: the model's own numerical accuracy, see run.numerical_tolerance)."""
    dt = float(np.median(np.diff(t_s)))
    w = max(1, int(round(window_s / dt)))
    m = moving_rms(r_deg, w)
    floor = sigma_deg if tol_deg is None else np.sqrt(sigma_deg ** 2 + moving_rms(tol_deg, w) ** 2)
    sig = m > k * floor
    out = []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], sig.astype(int), [0]])))
    for a, b in zip(idx[::2], idx[1::2]):
        t0, t1 = float(t_s[a]), float(t_s[b - 1])
        if out and t0 - out[-1][1] < GAP_S:
            out[-1][1] = t1
        else:
            out.append([t0, t1])
    return [[round(a, 4), round(b, 4)] for a, b in out if b - a >= MIN_WINDOW_S]


def regime_table(rec, r_deg: np.ndarray, regs: list, sigma_deg: float) -> list[dict]:
    rows = []
    for g in regs:
        n = int(g.mask.sum())
        if n == 0:
            continue
        rr = r_deg[g.mask]
        rms = float(np.sqrt(np.mean(rr ** 2)))
        rows.append({"regime": g.name, "samples": n, "rms_deg": rms, "mean_deg": float(np.mean(rr)),
                     "significant": bool(rms > REGIME_K * sigma_deg and n * rec.dt_s >= REGIME_MIN_S)})
    return rows


def ljung_box(r: np.ndarray, lags: int = 20) -> float:
    """p-value of the Ljung-Box whiteness test (small: the residual is not white)."""
    r = np.asarray(r, float) - np.mean(r)
    n = r.size
    v = float(r @ r)
    if v <= 0:
        return 1.0
    rho = np.array([float(r[:-k] @ r[k:]) / v for k in range(1, lags + 1)])
    q = n * (n + 2) * float(np.sum(rho ** 2 / (n - np.arange(1, lags + 1))))
    return float(stats.chi2.sf(q, lags))


def input_xcorr(r: np.ndarray, u: np.ndarray, max_lag: int = 50) -> tuple[float, float]:
    """(max |rho_ru(tau)| over tau = 0..max_lag, 99 % bound): does the input still explain the residual?"""
    r = np.asarray(r, float) - np.mean(r)
    u = np.asarray(u, float) - np.mean(u)
    den = math.sqrt(float(r @ r) * float(u @ u))
    if den <= 0:
        return 0.0, 2.58 / math.sqrt(r.size)
    best = max(abs(float(r[k:] @ u[:r.size - k])) / den for k in range(0, max_lag + 1))
    return best, 2.58 / math.sqrt(r.size)


def describe(rec, r_deg: np.ndarray, regs: list, sigma_deg: float, window_mask: np.ndarray) -> str:
    """What an unexplained residual looks like: its correlation with velocity sign, angle, current, time."""
    y = rec.angle_deg
    v = np.gradient(smooth(y, 15), rec.dt_s)
    m = window_mask
    if m.sum() < 10:
        m = np.ones_like(m)
    feats = {"velocity sign": np.sign(v), "angle": y, "voltage": rec.voltage_V, "time": rec.t_s}
    if rec.current_A is not None:
        feats["current"] = rec.current_A
    best, bc = None, 0.0
    for nm, f in feats.items():
        fm, rm = f[m], r_deg[m]
        if np.std(fm) == 0 or np.std(rm) == 0:
            continue
        c = float(np.corrcoef(fm, rm)[0, 1])
        if abs(c) > abs(bc):
            best, bc = nm, c
    sign = "positive" if float(np.mean(r_deg[m])) > 0 else "negative"
    txt = f"model reads {sign} of the recording on average ({float(np.mean(r_deg[m])):+.3f} deg)"
    if best is not None and abs(bc) > 0.3:
        txt += f"; residual follows {best} (correlation {bc:+.2f})"
    return txt
