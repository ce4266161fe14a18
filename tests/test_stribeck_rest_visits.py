"""A speed table's knots are visited by sliding only: the readings of a plate at rest move by the noise, which
reads as 0.01-0.1 rad/s of either sign (shapes.resting_mask; docs/diagnosis-history.md, round 34 x34stribeck)."""
from __future__ import annotations

import dataclasses

import numpy as np

from etb_gym.components import effects_maps as mx
from etb_gym.diagnose import shapes as S
from etb_gym.diagnose.model import prepare
from etb_gym.recordings import Recording

GRID = np.array([0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 9.0])


def _data(seed=0):
    """1.5 s at rest, a 0.5 s opening ramp at 1 rad/s, 1.5 s at rest; readings with 0.03 deg of noise."""
    dt = 1e-3
    t = np.arange(0.0, 3.5, dt)
    ang = np.where(t < 1.5, 20.0, np.where(t < 2.0, 20.0 + np.degrees(1.0) * (t - 1.5), 20.0 + np.degrees(0.5)))
    y = ang + 0.03 * np.random.default_rng(seed).standard_normal(t.size)
    rec = Recording("rest_ramp", t, np.full(t.size, 3.0), y)
    return prepare([rec], 12.0)


def _term():
    return S.MapTerm("stribeck_friction_map", "friction", mx.SpeedFrictionMap, GRID, ("opening_Nm", "closing_Nm"),
                     0.005, "N m", (("presliding_rad", 2e-3),))


def test_the_rest_runs_cover_the_holds_and_not_the_ramp():
    data = _data()
    rest = S.resting_mask(data)
    t = data.recs[0].rec.t_s
    assert rest.size == t.size
    assert np.mean(rest[(t > 0.2) & (t < 1.4)]) > 0.8 and np.mean(rest[(t > 2.2) & (t < 3.3)]) > 0.8
    assert not np.any(rest[(t > 1.6) & (t < 1.9)])


def test_a_plate_at_rest_visits_no_speed_knot_while_its_readings_noise_would():
    data = _data()
    n = GRID.size
    v = S.visit_time_s(_term(), data)
    w = S.data_speeds_rad_s(data)
    dt = data.recs[0].rec.dt_s
    noise = S._hat_time(np.abs(w[w < 0]), GRID, dt)        # every closing reading, rest included
    low = slice(1, 4)                                        # the knots at 0.01-0.1 rad/s
    assert np.all(noise[low] >= S.VISIT_MIN_S)             # the noise at rest reads as slow closing motion ...
    assert np.all(v[n:][low] < S.VISIT_MIN_S)              # ... which visits no closing knot
    assert np.all(v[:n][low] < S.VISIT_MIN_S)              # nor an opening one
    k1 = int(np.argmin(np.abs(GRID - 1.0)))
    assert v[k1] > 0.2                                       # the ramp at 1 rad/s is sliding: visited


def test_a_closed_loops_rest_runs_stay_counted():
    """The controller holds the plate against the band at its set points (the observer sees the level there):
    the rule is the open loop's."""
    data = _data()
    closed = dataclasses.replace(data, recs=[dataclasses.replace(rd, residual="observer")
                                             for rd in data.recs])
    assert not np.any(S.resting_mask(closed))
    w = S.data_speeds_rad_s(closed)
    n = GRID.size
    v = S.visit_time_s(_term(), closed)
    assert np.allclose(v[n:], S._hat_time(np.abs(w[w < 0]), GRID, data.recs[0].rec.dt_s))
    assert np.all(v[n:][1:4] >= S.VISIT_MIN_S)
