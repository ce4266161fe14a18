"""The states a twin's training recordings covered, and a residual split inside / outside them (issue 15).

A twin is fitted to the recordings it was given. Where they only *passed through* an angle, the fit sees a torque
balance there for a few milliseconds, mixed with inertia and friction; where they *held* the plate, it sees the
static balance (spring, friction, angle-dependent torques against the motor's torque) directly. A held-out
recording that holds the plate at an angle the training recordings only passed through tests the twin outside its
evidence. scripts/twin_coverage.py uses this to ask whether the twin's held-out error sits outside the
training's states; measured on 11 survey cases it does not (docs/diagnosis.md, "Why twins miss held-out
recordings"), so the envelope is a measuring tool and is not written into the report.

The envelope is the time the training recordings spent per angle bin, split by motion: ``held`` (the measured
speed below ``HELD_SPEED_DEG_S``), ``opening`` and ``closing``. A held state is covered when the recordings held
the plate in its angle bin for at least ``MIN_DWELL_S``; a moving state when they passed through the bin in that
direction at all. The measured speed is the central difference of the angle,
smoothed over ``SMOOTH_S`` (the sensor noise divided down to well below the held threshold).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ANGLE_BIN_DEG = 1.0          # angle bins of the envelope
HELD_SPEED_DEG_S = 10.0      # |speed| below: the plate is held (a closed loop at its set point, a stop, a dwell)
MIN_DWELL_S = 0.05           # time held in an angle bin for the held state to count as covered
SMOOTH_S = 0.02              # speed: central difference over this span of a moving average of this span
MOTIONS = ("held", "opening", "closing")


def speed_deg_s(t_s: np.ndarray, angle_deg: np.ndarray, smooth_s: float = SMOOTH_S) -> np.ndarray:
    """The measured angle's speed [deg/s]: moving average over ``smooth_s``, then a central difference over it."""
    t_s, angle_deg = np.asarray(t_s, float), np.asarray(angle_deg, float)
    if t_s.shape != angle_deg.shape or t_s.size < 2:
        raise ValueError(f"speed_deg_s: t_s ({t_s.shape}) and angle_deg ({angle_deg.shape}) must be equal-length "
                         "1-D arrays of at least 2 samples")
    dt = float(np.median(np.diff(t_s)))
    if not dt > 0:
        raise ValueError(f"speed_deg_s: the time column must increase (median step {dt} s)")
    w = max(1, int(round(smooth_s / dt)))
    pad = np.pad(angle_deg, (w // 2, w - 1 - w // 2), mode="edge")
    sm = np.convolve(pad, np.ones(w) / w, mode="valid")
    h = max(1, w // 2)
    ext = np.pad(sm, h, mode="edge")
    return (ext[2 * h:] - ext[:-2 * h]) / (2 * h * dt)


def motion_index(speed: np.ndarray) -> np.ndarray:
    """0 held, 1 opening, 2 closing (the order of ``MOTIONS``)."""
    return np.where(np.abs(speed) < HELD_SPEED_DEG_S, 0, np.where(speed > 0, 1, 2))


@dataclass(frozen=True)
class Envelope:
    """Time [s] the training recordings spent per (motion, angle bin); bin k spans lo_deg + k * bin_deg."""

    lo_deg: float
    bin_deg: float
    dwell_s: np.ndarray          # shape (3, bins): MOTIONS x angle bins

    def _bins(self, angle_deg) -> tuple[np.ndarray, np.ndarray]:
        k = np.floor((np.asarray(angle_deg, float) - self.lo_deg) / self.bin_deg).astype(int)
        inside = (k >= 0) & (k < self.dwell_s.shape[1])
        return np.clip(k, 0, self.dwell_s.shape[1] - 1), inside

    def covered(self, t_s, angle_deg, memory_s: float = 0.0) -> np.ndarray:
        """Per sample of a recording (its time and measured angle): is its state inside the envelope -- and with
        ``memory_s`` > 0, were the states of the preceding ``memory_s`` too (a replay carries an error made outside
        the envelope on into the next states)?"""
        k, inside = self._bins(angle_deg)
        m = motion_index(speed_deg_s(t_s, angle_deg))
        cov = inside & (self.dwell_s[m, k] >= self._need()[m])
        if memory_s < 0:
            raise ValueError(f"Envelope.covered: memory_s = {memory_s} is invalid: expected 0 or more seconds")
        w = int(round(memory_s / float(np.median(np.diff(t_s))))) if memory_s > 0 else 0
        if w > 0:                                       # uncovered if any of the last w samples was
            out = np.concatenate([np.zeros(w, int), np.cumsum(~cov)])
            cov = (out[w:] - out[:-w]) == 0
        return cov

    def _need(self) -> np.ndarray:
        """Per motion, the time in a bin that covers it: MIN_DWELL_S held, any sample moving."""
        return np.array([MIN_DWELL_S, 1e-12, 1e-12])

    def ranges_deg(self, motion: str) -> list[list[float]]:
        """The covered angle intervals [lo, hi] of one motion, adjacent bins merged."""
        i = MOTIONS.index(motion)
        ok = self.dwell_s[i] >= self._need()[i]
        out = []
        for k in np.flatnonzero(ok):
            a, b = float(self.lo_deg + k * self.bin_deg), float(self.lo_deg + (k + 1) * self.bin_deg)
            if out and abs(out[-1][1] - a) < 1e-9:
                out[-1][1] = b
            else:
                out.append([a, b])
        return out

    def as_dict(self) -> dict:
        return {"angle_bin_deg": self.bin_deg, "held_speed_deg_s": HELD_SPEED_DEG_S, "min_dwell_s": MIN_DWELL_S,
                **{f"{m}_deg": self.ranges_deg(m) for m in MOTIONS},
                "held_s": float(self.dwell_s[0].sum()), "moving_s": float(self.dwell_s[1:].sum())}


def from_recordings(recs, bin_deg: float = ANGLE_BIN_DEG) -> Envelope:
    """The envelope of recordings (objects with ``t_s`` and ``angle_deg``: etb_gym.recordings.Recording)."""
    if not recs:
        raise ValueError("envelope.from_recordings: no recordings given")
    if not bin_deg > 0:
        raise ValueError(f"envelope.from_recordings: bin_deg = {bin_deg} is invalid: expected a positive angle")
    lo = np.floor(min(float(np.min(r.angle_deg)) for r in recs) / bin_deg) * bin_deg
    hi = max(float(np.max(r.angle_deg)) for r in recs)
    n = int(np.floor((hi - lo) / bin_deg)) + 1
    dwell = np.zeros((len(MOTIONS), n))
    for r in recs:
        k = np.clip(np.floor((r.angle_deg - lo) / bin_deg).astype(int), 0, n - 1)
        m = motion_index(speed_deg_s(r.t_s, r.angle_deg))
        np.add.at(dwell, (m, k), r.dt_s)
    return Envelope(float(lo), float(bin_deg), dwell)


def split_rms(resid_deg: np.ndarray, covered: np.ndarray) -> dict:
    """A residual's RMS inside and outside the envelope, and the shares of time and of squared error outside."""
    r2 = np.asarray(resid_deg, float) ** 2
    c = np.asarray(covered, bool)
    if r2.shape != c.shape:
        raise ValueError(f"split_rms: residual {r2.shape} and mask {c.shape} differ in length")

    def rms(x):
        return float(np.sqrt(np.mean(x))) if x.size else None

    tot = float(r2.sum())
    return {"rms_covered_deg": rms(r2[c]), "rms_uncovered_deg": rms(r2[~c]), "time_uncovered": float(np.mean(~c)),
            "sq_error_uncovered": float(r2[~c].sum() / tot) if tot > 0 else 0.0}

