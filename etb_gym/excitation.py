"""Standard input signals (duty sequences at the control period) used by tests, scripts and the docs."""
from __future__ import annotations

import numpy as np


def rich_excitation(duration_s: float = 2.0, dt: float = 1e-3) -> np.ndarray:
    """2 s of duty that exercises every regime: steps, a ramp to the open stop, a push into the closed
    stop, a release from full open, and a chirp (1 -> 15 Hz) that crosses limp-home repeatedly.

    Scaled to ``duration_s`` (the segments keep their proportions)."""
    n = int(round(duration_s / dt))
    s = np.linspace(0.0, 1.0, n, endpoint=False)  # normalized time
    d = np.zeros(n)
    seg = lambda a, b: (s >= a) & (s < b)
    d[seg(0.00, 0.08)] = 0.45          # step open
    d[seg(0.08, 0.15)] = 0.25          # step down
    d[seg(0.15, 0.22)] = -0.35         # into the closed stop
    m = seg(0.22, 0.40)                # ramp to full duty: reaches the open stop
    d[m] = np.linspace(0.0, 1.0, m.sum())
    d[seg(0.40, 0.47)] = 0.0           # release from full open
    m = seg(0.47, 1.0)                 # chirp around limp-home, 1 -> 15 Hz
    tc = (s[m] - 0.47) * duration_s
    T = tc[-1] if tc.size else 1.0
    f0, f1 = 1.0, 15.0
    phase = 2 * np.pi * (f0 * tc + 0.5 * (f1 - f0) / T * tc ** 2)
    d[m] = 0.12 + 0.5 * np.sin(phase)
    return d


def voltage_steps(levels_V=(4.0, 5.0, 6.0), hold_s: float = 0.5, dt: float = 1e-3) -> dict:
    """The paper's validation steps (sec. 7): one constant-voltage sequence per level."""
    n = int(round(hold_s / dt))
    return {v: np.full(n, float(v)) for v in levels_V}
