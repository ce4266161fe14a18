"""Where a stop's angle starts its screening fit (explain.reached_stop, round 24): at the open-loop recordings'
furthest reading when neither they nor the model's plate reach the nameplate's stop, else at the nameplate's stop.
No simulation: the recordings are stand-ins holding only their angles, the model's angle is given."""
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


def _reached(p, base, data, model=None):
    """reached_stop with the model's plate where the readings are (``model``: the same shift for all)."""
    return reached_stop(p, base, data, [rd.rec.angle_deg + (model or 0.0) for rd in data.recs])


def _stop_params():
    base = make_plant("3B")
    spec = Spec(base, (CANDIDATES["end_stop_compliance"],))
    p = {q.name: q for owner, q in spec.params if owner == "end_stop_compliance"}
    return base, spec, p


def test_a_stop_the_recordings_never_reach_starts_at_the_furthest_reading():
    base, spec, p = _stop_params()
    data = _data(np.linspace(-0.05, 88.48, 50), np.linspace(10.0, 60.0, 20))    # open stop nominal 90 deg
    v = _reached(p["open_rad"], base, data)
    assert v is not None
    assert abs(math.degrees(p["open_rad"].init + p["open_rad"].scale * v) - 88.48) < 1e-9
    assert _reached(p["closed_rad"], base, data) is None       # the plate reached the closed stop (-0.05 deg)
    assert _reached(p["stiffness_Nm_per_rad"], base, data) is None   # not a stop angle
    x = extend(np.zeros(len(spec.nominal)), spec, data, [rd.rec.angle_deg for rd in data.recs])
    k = len(spec.nominal)
    assert x[k] == v and x[k + 1] == 0.0 and x[k + 2] == 0.0
    assert np.all(extend(np.zeros(len(spec.nominal)), spec) == 0.0)     # without data: the nameplate's start


def test_a_stop_start_stays_where_the_plate_reached_it_or_never_came_near():
    base, _, p = _stop_params()
    assert _reached(p["open_rad"], base, _data(np.linspace(0.0, 90.3, 40))) is None    # pressed the stop
    # the readings stop short (a sensor offset, say) but the model's plate presses the stop: it has a gradient there
    assert _reached(p["open_rad"], base, _data(np.linspace(0.0, 89.5, 40)), model=0.6) is None
    # resting at limp-home is not a plate driven toward the closed stop
    assert _reached(p["closed_rad"], base, _data(np.linspace(2.97, 80.0, 40))) is None
    assert _reached(p["open_rad"], base, _data(np.linspace(0.0, 70.0, 40))) is None    # never near it (bound 84)
    # the closed stop: the plate held above it but driven below limp-home (3 deg) starts it at its lowest reading
    v = _reached(p["closed_rad"], base, _data(np.linspace(1.2, 80.0, 40)))
    assert v is not None and abs(math.degrees(p["closed_rad"].init + p["closed_rad"].scale * v) - 1.2) < 1e-9
    assert _reached(p["closed_rad"], base, _data(np.linspace(4.0, 80.0, 40))) is None  # never below limp-home
    # a closed loop's extremes are where its reference went: no start moves
    closed = _data(np.linspace(2.1, 83.5, 40), residual="observer")
    assert _reached(p["closed_rad"], base, closed) is None and _reached(p["open_rad"], base, closed) is None
