"""The measurement side: sensor transforms, resolution detection, rest runs and the noise floor.

Sensor effects act on the reading, not on the plate (sensor.py holds the core equation):

    y(t) = q * round((g * phi(t - tau) + y_0) / q)       angle in degrees at this documented edge

g gain, y_0 offset [deg], tau delay [s] (fractional: linear interpolation between samples), q resolution
(0 = none). The diagnosis fits g, y_0 and tau by output error like any other parameter; q is read off
the recorded values (``detect_resolution``), since rounding has no useful derivative.

Noise floor: while friction holds the plate still the true angle is constant, so the spread of the
reading about a cubic trend (presliding creep) inside such *rest runs* is the sensor noise, coloured or not, plus quantization.
Without rest runs it falls back to the second-difference estimate sigma^2 = E[(y[k+1] - 2y[k] + y[k-1])^2]/6
(the largest 5 % dropped as motion; where motion fills more, the differences within 5 robust deviations:
:func:`quiet_sigma`).
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from ..components.effects_maps import SensorMap, SensorMapParams
from ..components.sensor import (PositionSensor, PositionSensorParams, ReadingFilterParams, fir_series,
                                 sensor_section, sensor_section_dict)

DEFAULT_RESOLUTION_DEG = 90.0 / 4096      # PositionSensorParams default: 12 bits over 90 deg
REST_TREND_DEGREE = 3                     # polynomial removed from each rest run before its spread is taken


@dataclasses.dataclass(frozen=True)
class SensorModel:
    """What the diagnosis assumes about the angle sensor (degrees at this edge). ``curve`` (a reading error over
    angle, effects_maps.SensorMapParams) and ``filter`` (a causal FIR kernel over samples,
    components.sensor.ReadingFilterParams) are the sensor-side maps learned once a sensing family is named
    (sensor_map.py); the order is the components.sensor docstring's: delay, curve, filter, gain and offset."""

    offset_deg: float = 0.0
    gain: float = 1.0
    delay_s: float = 0.0
    resolution_deg: float = 0.0
    curve: SensorMapParams | None = None
    filter: ReadingFilterParams | None = None

    def true_reading(self, t_s: np.ndarray, angle_deg: np.ndarray) -> np.ndarray:
        """The angle after the delay, the curve and the filter, before gain and offset [deg]."""
        a = np.asarray(angle_deg, float)
        if self.delay_s > 0.0:
            a = np.interp(t_s - self.delay_s, t_s, a)          # holds a[0] before the start
        if self.curve is not None:
            a = SensorMap(self.curve).apply_deg(a)
        if self.filter is not None and a.size:
            a = fir_series(np.ascontiguousarray(a, dtype=float), np.asarray(self.filter.weights, float))
        return a

    def apply(self, t_s: np.ndarray, angle_deg: np.ndarray, quantize: bool = False) -> np.ndarray:
        """The reading for a true angle trajectory sampled at ``t_s``."""
        a = self.true_reading(t_s, angle_deg)
        sensor = PositionSensor(PositionSensorParams(
            noise_std_rad=0.0, resolution_rad=math.radians(self.resolution_deg) if quantize else 0.0,
            offset_rad=math.radians(self.offset_deg), gain=self.gain))
        return np.degrees(sensor.transform(np.radians(a), 0.0))

    def invert(self, reading_deg):
        """The true angle of a reading at rest (delay and filter do not matter at rest); arrays too."""
        a = (np.asarray(reading_deg, float) - self.offset_deg) / self.gain
        if self.curve is not None:
            a = SensorMap(self.curve).invert_deg(a)
        return float(a) if np.ndim(a) == 0 else a

    def lag_periods(self, dt_s: float) -> float:
        """How many sample periods the reading lags the plate: the delay and the filter's centre of mass."""
        return self.delay_s / dt_s + (self.filter.mean_lag_periods if self.filter is not None else 0.0)

    def lag_s(self, dt_s: float) -> float:
        """:meth:`lag_periods` in seconds (the delay itself where there is no filter)."""
        return self.delay_s + (self.filter.mean_lag_periods * dt_s if self.filter is not None else 0.0)

    def section(self) -> dict:
        """This sensor as a plant file's ``[sensor]`` section (docs/plant-file.md; radians there)."""
        return sensor_section_dict(math.radians(self.offset_deg), self.gain, self.delay_s, self.curve, self.filter)

    def section_maps(self) -> dict:
        """The learned maps of :meth:`section` only (report.json's ``sensor``: ``curve``, ``filter``)."""
        return {k: v for k, v in self.section().items() if k in ("curve", "filter")}

    @classmethod
    def from_section(cls, d: dict, resolution_deg: float = 0.0) -> "SensorModel":
        """The sensor of a plant file's ``[sensor]`` section (checked by components.sensor.sensor_section)."""
        s = sensor_section(d)
        return cls(math.degrees(s["offset_rad"]), s["gain"], s["delay_s"], resolution_deg, s["curve"], s["filter"])


def detect_resolution(y: np.ndarray, rel_tol: float = 0.08) -> float:
    """The grid step of quantized readings (0.0 if the values do not lie on a grid)."""
    y = np.asarray(y, float)
    dy = np.abs(np.diff(y))
    dy = dy[dy > 1e-9 * max(1.0, float(np.max(np.abs(y))))]
    if dy.size < 10:
        return 0.0
    q = float(np.percentile(dy, 1))
    if q <= 0:
        return 0.0
    # refine: the step is the smallest cluster of differences
    small = dy[dy < 1.5 * q]
    q = float(np.median(small))
    k = np.round(dy / q)
    if np.median(np.abs(dy / q - k)) > rel_tol:
        return 0.0
    frac = (y - y[0]) / q
    if np.median(np.abs(frac - np.round(frac))) > rel_tol:
        return 0.0
    return q


def smooth(y: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples (edges shrink the window)."""
    n = max(1, int(n))
    c = np.cumsum(np.concatenate([[0.0], y]))
    k = np.arange(y.size)
    lo = np.clip(k - n // 2, 0, y.size)
    hi = np.clip(k + n // 2 + 1, 0, y.size)
    return (c[hi] - c[lo]) / (hi - lo)


def rest_runs(t_s: np.ndarray, y_deg: np.ndarray, band_deg: float, min_len: int = 40) -> list[tuple[int, int]]:
    """Runs [a, b) in which the reading stays inside +-band_deg of the run's running median: the plate
    is held by friction (or a stop). Found greedily from left to right."""
    ys = smooth(y_deg, 9)
    runs = []
    a = 0
    n = y_deg.size
    while a < n:
        b = a + 1
        lo = hi = ys[a]
        while b < n:
            lo2, hi2 = min(lo, ys[b]), max(hi, ys[b])
            if hi2 - lo2 > 2 * band_deg:
                break
            lo, hi = lo2, hi2
            b += 1
        if b - a >= min_len:
            runs.append((a, b))
            a = b
        else:
            a += max(1, (b - a) // 2)
    return runs


def second_difference_sigma(y: np.ndarray) -> float:
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    d2 = d2[np.abs(d2) <= np.percentile(np.abs(d2), 95)]     # motion and contacts out
    return float(math.sqrt(np.mean(d2 ** 2) / 6.0)) if d2.size else 0.0


MOTION_RATIO = 3.0     # the 95 % second-difference estimate this far above the robust one: motion, not noise
ROBUST_CLIP = 5.0      # second differences beyond this many robust standard deviations are motion


def quiet_sigma(y: np.ndarray, resolution: float = 0.0) -> float:
    """The noise's standard deviation from second differences, robust to motion that fills more than the 5 %
    :func:`second_difference_sigma` drops (a slow sample rate, a plate that moves throughout): when that
    estimate exceeds MOTION_RATIO times the median-absolute-deviation estimate (at least one quantum of the
    reading, ``resolution``), the differences within ROBUST_CLIP robust deviations give it instead. On a
    recording whose second differences are noise both estimates agree and the 95 % one is kept."""
    s = second_difference_sigma(y)
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    if d2.size < 8:
        return s
    mad = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    robust = max(mad, float(resolution)) / math.sqrt(6.0)
    if robust <= 0.0 or s <= MOTION_RATIO * robust:
        return s
    quiet = d2[np.abs(d2) <= ROBUST_CLIP * math.sqrt(6.0) * robust]
    return float(math.sqrt(np.mean(quiet ** 2) / 6.0)) if quiet.size else robust


def _ar_apply(x: np.ndarray, a: float) -> np.ndarray:
    """R x for the AR(1) correlation matrix R_jk = a^|j-k| (a forward and a backward recursion, O(n)), along
    the first axis (a vector, or each column of a matrix)."""
    from scipy.signal import lfilter
    if a == 0.0:
        return x.copy()
    f = lfilter([1.0], [1.0, -a], x, axis=0)
    b = lfilter([1.0], [1.0, -a], x[::-1], axis=0)[::-1]
    return f + b - x


@functools.lru_cache(maxsize=64)
def _trend_basis(n: int) -> np.ndarray:
    """An orthonormal basis of the polynomials of degree REST_TREND_DEGREE over ``n`` samples (read only: cached,
    since :func:`noise_colour`'s search asks for the same run lengths many times)."""
    Q, _ = np.linalg.qr(np.vander(np.linspace(-1.0, 1.0, n), REST_TREND_DEGREE + 1))
    Q.setflags(write=False)
    return Q


def _detrended_moments(n: int, a: float) -> tuple[float, float]:
    """(lag-0, lag-1) sums expected of unit-variance AR(1) noise of coefficient ``a`` after a least-squares
    polynomial of degree REST_TREND_DEGREE is removed from ``n`` samples: tr(M) and the sum of M's
    first off-diagonal, M = (I - H) R (I - H), H the polynomial's hat matrix. At a = 0, tr(M) = n - degree - 1."""
    Q = _trend_basis(n)
    RQ = _ar_apply(Q, a)
    QRQ = Q.T @ RQ
    c0 = n - float(np.trace(QRQ))                                   # tr(R) - 2 tr(H R) + tr(H R H)
    lag = lambda X, Y: float(np.sum(X[1:] * Y[:-1]))               # noqa: E731 -- sum_k X[k+1] Y[k]
    LQ = Q[1:].T @ Q[:-1]                                           # Q^T L Q, L the shift down
    c1 = ((n - 1) * a - sum(lag(Q[:, j], RQ[:, j]) + lag(RQ[:, j], Q[:, j]) for j in range(Q.shape[1]))
          + float(np.trace(LQ @ QRQ)))
    return c0, c1


def _median_share(k: float) -> float:
    """Median of chi-square(k) / k (Wilson-Hilferty), at least 0.3 (k below 1)."""
    return max((1.0 - 2.0 / (9.0 * k)) ** 3, 0.3)


COLOUR_MIN = 0.6      # below it the noise counts as white: the colour's correction (a few %) is within the
                      # estimate's scatter (creep and quantization alone give a ~ 0.1-0.3 on white noise)
MAX_COLOUR = 0.98      # the largest AR(1) coefficient the noise floor corrects for


def noise_colour(residuals: list) -> float:
    """The AR(1) coefficient a of the reading's noise from the detrended rest runs: the one whose expected
    lag-1 / lag-0 ratio after the detrend (:func:`_detrended_moments`) matches the runs' pooled ratio
    (the detrend alone makes white noise look anti-correlated, so the raw ratio would understate a)."""
    r0 = sum(float(np.sum(r ** 2)) for r in residuals)
    r1 = sum(float(np.sum(r[1:] * r[:-1])) for r in residuals)
    if r0 <= 0.0:
        return 0.0
    target = r1 / r0

    def ratio(a):
        m = [_detrended_moments(r.size, a) for r in residuals]
        return sum(c1 for _, c1 in m) / sum(c0 for c0, _ in m)
    if ratio(0.0) >= target:
        return 0.0
    if ratio(MAX_COLOUR) <= target:
        return MAX_COLOUR
    lo, hi = 0.0, MAX_COLOUR
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ratio(mid) < target else (lo, mid)
    return 0.5 * (lo + hi)


def detrended_runs(y_deg: np.ndarray, runs: list) -> list:
    """The reading inside each rest run (a, b) about its REST_TREND_DEGREE trend (presliding creep, not a
    straight line, removed)."""
    res = []
    for a, b in runs:
        seg = y_deg[a:b]
        k = np.arange(b - a)
        res.append(seg - np.polyval(np.polyfit(k, seg, REST_TREND_DEGREE), k))
    return res


def median_colour(res: list) -> float:
    """The median over detrended rest runs of each run's :func:`noise_colour` (a run with creep beyond the trend
    is an outlier); 0 without runs."""
    return float(np.median([noise_colour([r]) for r in res])) if res else 0.0


def _rest_spread(y_deg: np.ndarray, runs: list) -> float:
    """The noise's standard deviation inside the rest ``runs``: each run about its cubic trend, scaled by
    the trend's expected share of coloured noise (:func:`noise_colour` when at least COLOUR_MIN,
    :func:`_detrended_moments`); the median over runs."""
    res = detrended_runs(y_deg, runs)
    colour = median_colour(res)
    colour = colour if colour >= COLOUR_MIN else 0.0
    v = []
    for r in res:
        c0 = max(_detrended_moments(r.size, colour)[0], 1.0)
        # the median of the runs is taken: a coloured run's sum of squares has fewer degrees of freedom
        # (k ~ c0 (1 - a^2) / (1 + a^2)) and a lower median (~ (1 - 2 / 9k)^3 of its mean) than a white one's
        k0, k = max(r.size - REST_TREND_DEGREE - 1, 1), max(c0 * (1 - colour ** 2) / (1 + colour ** 2), 1.0)
        v.append(float(np.sum(r ** 2)) / c0 * _median_share(k0) / _median_share(k))
    return math.sqrt(float(np.median(v)))                  # runs with hidden slow motion do not count


BAND_SIGMAS = 4.0      # a rest run's reading stays within this many noise deviations of its running median
BAND_ROUNDS = 3        # times the band is widened to the runs' own spread (coloured noise)
WIDEN_RATIO = 2.0      # ... when the runs' spread exceeds the band's deviation this many times (AR(1) noise a >~ 0.7)


def noise_floor(t_s: np.ndarray, y_deg: np.ndarray, resolution_deg: float) -> tuple[float, list]:
    """(sigma_deg, rest runs): the standard deviation of the reading about the true angle, from the rest runs
    (:func:`_rest_spread`). The runs are found in a band of BAND_SIGMAS second-difference deviations; coloured
    noise is smoother than white noise of its size, so its second differences understate it, the band only
    admits runs where the noise happened to stay small, and the spread comes out low. So while the runs'
    spread exceeds WIDEN_RATIO times the band's deviation, the band is widened to it and the runs found again (up to
    BAND_ROUNDS times; on white noise the two agree and nothing changes)."""
    s_d2 = quiet_sigma(y_deg, resolution_deg)
    band = max(BAND_SIGMAS * s_d2, 1.5 * resolution_deg, 1e-3)
    runs = rest_runs(t_s, y_deg, band)
    s = _rest_spread(y_deg, runs) if runs else s_d2
    for _ in range(BAND_ROUNDS if runs else 0):
        if s <= WIDEN_RATIO * band / BAND_SIGMAS:
            break
        band = BAND_SIGMAS * s
        wider = rest_runs(t_s, y_deg, band)
        if not wider:
            break
        runs, s = wider, _rest_spread(y_deg, wider)
    # quantization error is part of the floor even when the held reading does not flicker
    return math.sqrt(max(s ** 2, resolution_deg ** 2 / 12.0)), runs
