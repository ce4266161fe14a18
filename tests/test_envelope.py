"""The twin's envelope (etb_gym.diagnose.envelope): held vs passed-through angles, coverage of another recording."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from etb_gym.diagnose import envelope as E


def _rec(t, angle):
    return SimpleNamespace(t_s=t, angle_deg=angle, dt_s=float(np.median(np.diff(t))))


def _ramp_hold(hold_at, hold_s=1.0, noise=0.03, seed=0):
    """Held at 10.5 deg, a ramp at 40 deg/s to ``hold_at``, held there."""
    t = np.arange(0.0, 2.0 + hold_s, 1e-3)
    ramp_end = 1.0 + (hold_at - 10.5) / 40.0
    a = np.where(t < 1.0, 10.5, np.where(t < ramp_end, 10.5 + 40.0 * (t - 1.0), hold_at))
    return t, a + np.random.default_rng(seed).normal(0.0, noise, t.size)


def test_speed_is_the_slope_and_quiet_when_held():
    t, a = _ramp_hold(50.5)
    v = E.speed_deg_s(t, a)
    assert abs(np.median(v[1200:1800]) - 40.0) < 0.5
    assert np.max(np.abs(v[100:900])) < E.HELD_SPEED_DEG_S / 2         # sensor noise alone is "held"


def test_envelope_holds_where_held_and_passes_where_moved():
    env = E.from_recordings([_rec(*_ramp_hold(30.5))])
    d = env.as_dict()
    assert d["held_deg"] == [[10.0, 11.0], [30.0, 31.0]]
    assert d["opening_deg"][0][0] <= 11.0 and d["opening_deg"][-1][1] >= 30.0 and d["closing_deg"] == []
    assert d["held_s"] + d["moving_s"] == pytest.approx(3.0, abs=0.01)
    # another recording over the same ramp, but holding at 20.5 deg (only passed through in training): the hold at
    # 20.5 is outside the envelope, the hold at 10.5 and the ramp up to it are inside
    t2 = np.arange(0.0, 3.0, 1e-3)
    a2 = np.where(t2 < 1.0, 10.5, np.where(t2 < 1.25, 10.5 + 40.0 * (t2 - 1.0), 20.5))
    cov = env.covered(t2, a2 + np.random.default_rng(1).normal(0.0, 0.03, t2.size))
    assert cov[100:900].all() and cov[1050:1200].all() and not cov[1400:].any()
    # with a memory, the samples after leaving an uncovered state stay outside for that long
    t3 = np.arange(0.0, 2.0, 1e-3)
    a3 = np.where(t3 < 1.0, 20.5, 10.5)
    first = [int(np.flatnonzero(env.covered(t3, a3, memory_s=m))[0]) for m in (0.0, 0.25)]
    assert 1000 <= first[0] < 1050 and abs(first[1] - first[0] - 250) <= 1
    s = E.split_rms(np.where(cov, 1.0, 3.0), cov)
    assert s["rms_covered_deg"] == pytest.approx(1.0) and s["rms_uncovered_deg"] == pytest.approx(3.0)
    assert s["time_uncovered"] == pytest.approx(np.mean(~cov))


def test_bad_inputs_fail_naming_what():
    with pytest.raises(ValueError, match="no recordings"):
        E.from_recordings([])
    with pytest.raises(ValueError, match="bin_deg = 0"):
        E.from_recordings([_rec(*_ramp_hold(20.5))], bin_deg=0.0)
    with pytest.raises(ValueError, match="memory_s = -1"):
        E.from_recordings([_rec(*_ramp_hold(20.5))]).covered(np.arange(3.0), np.zeros(3), memory_s=-1.0)
    with pytest.raises(ValueError, match="equal-length"):
        E.speed_deg_s(np.arange(3.0), np.arange(4.0))
    with pytest.raises(ValueError, match="differ in length"):
        E.split_rms(np.zeros(3), np.ones(4, bool))
