"""Where a stop's angle starts its screening fit (explain.reached_stop, round 24): at the recordings' furthest
angle when they never reach the nameplate's stop, else at the nameplate's stop. No simulation: the recordings are
stand-ins holding only their angles."""
import math
from types import SimpleNamespace

import numpy as np

from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.explain import extend, reached_stop
from etb_gym.diagnose.model import Spec
from etb_gym.plant import make_plant


def _data(*angle_deg, residual="replay"):
    return SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=np.asarray(a, float), n=len(a)),
                                                 residual=residual) for a in angle_deg])


def _stop_params():
    base = make_plant("3B")
    spec = Spec(base, (CANDIDATES["end_stop_compliance"],))
    p = {q.name: q for owner, q in spec.params if owner == "end_stop_compliance"}
    return base, spec, p


def test_a_stop_the_recordings_never_reach_starts_at_the_furthest_reading():
    base, spec, p = _stop_params()
    data = _data(np.linspace(-0.05, 88.48, 50), np.linspace(10.0, 60.0, 20))    # open stop nominal 90 deg
    v = reached_stop(p["open_rad"], base, data)
    assert v is not None
    assert abs(math.degrees(p["open_rad"].init + p["open_rad"].scale * v) - 88.48) < 1e-9
    assert reached_stop(p["closed_rad"], base, data) is None       # the plate reached the closed stop (-0.05 deg)
    assert reached_stop(p["stiffness_Nm_per_rad"], base, data) is None   # not a stop angle
    x = extend(np.zeros(len(spec.nominal)), spec, data)
    k = len(spec.nominal)
    assert x[k] == v and x[k + 1] == 0.0 and x[k + 2] == 0.0
    assert np.all(extend(np.zeros(len(spec.nominal)), spec) == 0.0)     # without data: the nameplate's start


def test_a_stop_start_stays_where_the_plate_reached_it_or_never_came_near():
    base, _, p = _stop_params()
    assert reached_stop(p["open_rad"], base, _data(np.linspace(0.0, 90.3, 40))) is None    # pressed the stop
    assert reached_stop(p["open_rad"], base, _data(np.linspace(0.0, 70.0, 40))) is None    # never near it (bound 84)
    # the closed stop: the plate held above it but driven below limp-home (3 deg) starts it at its lowest reading
    v = reached_stop(p["closed_rad"], base, _data(np.linspace(1.2, 80.0, 40)))
    assert v is not None and abs(math.degrees(p["closed_rad"].init + p["closed_rad"].scale * v) - 1.2) < 1e-9
    assert reached_stop(p["closed_rad"], base, _data(np.linspace(4.0, 80.0, 40))) is None  # never below limp-home
    # a closed loop's extremes are where its reference went: no start moves
    closed = _data(np.linspace(2.1, 83.5, 40), residual="observer")
    assert reached_stop(p["closed_rad"], base, closed) is None and reached_stop(p["open_rad"], base, closed) is None
