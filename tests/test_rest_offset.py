"""closed_twin.rest_offset (round 33): a closed loop's reading offset, which the loop trades exactly against the
spring's preload above limp-home, moved to where the unpowered rest before the loop engages reads limp-home."""
import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from etb_gym.diagnose import closed_twin as CT
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.fit import FitResult, Spec
from etb_gym.plant import make_plant


def _rec(rest_reading, rest_n=200, n=1000, residual="observer", spread=0.0):
    v = np.zeros(n)
    v[rest_n:] = 3.0
    y = np.full(n, 40.0)
    y[:rest_n] = rest_reading + spread * np.sin(np.arange(rest_n))
    return NS(rec=NS(voltage_V=v, angle_deg=y, dt_s=1e-3), noise_deg=0.012, resolution_deg=0.022, residual=residual)


def _run(monkeypatch, recs, cost=lambda x: 100.0):
    spec = Spec(make_plant("3B"), (CANDIDATES["sensor_offset_gain"],))
    final = FitResult(spec, np.zeros(len(spec.params)), 0.0, 0, None, 0)
    monkeypatch.setattr(CT, "_replay_cost", lambda fr, d: (cost(fr.x), 100))
    note = {}
    out = CT.rest_offset(final, NS(recs=recs), note)
    return final, out, note.get("rest_offset")


def test_the_unpowered_rest_sets_the_offset_and_the_preload_follows_along_the_trade(monkeypatch):
    """The rest reads limp-home + 0.2 deg (the model: no offset, gain 1, no bow): the offset takes the 0.2 deg
    and the preload R * 0.2 deg in rad, so the spring torque at every reading above limp-home stays."""
    lh = math.degrees(make_plant("3B").limp_home_rad)
    final, out, info = _run(monkeypatch, [_rec(lh + 0.2)])
    v0, v1 = final.spec.values(final.x), out.spec.values(out.x)
    rate = make_plant("3B").spring.params.rate_Nm_per_rad
    assert info["kept"] and info["offset_shift_deg"] == pytest.approx(0.2, abs=1e-9)
    assert v1["sensor_offset_gain.offset_deg"] == pytest.approx(v0["sensor_offset_gain.offset_deg"] + 0.2, abs=1e-9)
    assert v1["spring.preload_Nm"] - v0["spring.preload_Nm"] == pytest.approx(rate * math.radians(0.2), rel=1e-6)


def test_the_move_is_refused_where_the_fits_cost_rises_by_more_than_its_noise(monkeypatch):
    lh = math.degrees(make_plant("3B").limp_home_rad)
    final, out, info = _run(monkeypatch, [_rec(lh + 0.2)], cost=lambda x: 100.0 if not np.any(x) else 200.0)
    assert out is final and not info["kept"]


def test_no_rest_before_the_loop_or_an_open_loop_leaves_the_fit(monkeypatch):
    lh = math.degrees(make_plant("3B").limp_home_rad)
    for recs in ([_rec(lh + 0.2, rest_n=5)], [_rec(lh + 0.2, spread=1.0)], [_rec(lh + 0.2, residual="replay")]):
        final, out, info = _run(monkeypatch, recs)
        assert out is final and info is None


def test_a_shift_within_the_readings_step_is_left(monkeypatch):
    """0.015 deg against a 0.022 deg resolution step: the rest's mean does not resolve it."""
    lh = math.degrees(make_plant("3B").limp_home_rad)
    final, out, info = _run(monkeypatch, [_rec(lh + 0.015)])
    assert out is final and info is None
