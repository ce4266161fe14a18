"""closed_twin.refit_weak: a closed loop's final model refitted on the replay only in the directions the observer
residual leaves open, kept where both halves of the replay gain (round 26). Linear stand-ins for the two
residuals: no simulation."""
import types

import numpy as np
import pytest

from etb_gym.diagnose import closed_twin as CT
from etb_gym.diagnose import fit as F

N = 400
T = np.linspace(0.0, 6.0, N)
V = np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)       # a level traded against the effect: the observer cannot see it
X_TRUE = np.array([0.2, -0.1, 0.4])
X_OBS = X_TRUE + 0.8 * V                             # the observer's optimum, off along the trade


class _Spec:
    params = [("nominal", types.SimpleNamespace(name="spring.rate_Nm_per_rad")),
              ("nominal", types.SimpleNamespace(name="spring.preload_Nm")),
              ("airflow_torque", types.SimpleNamespace(name="quadratic_Nm"))]

    def bounds(self):
        return np.full(3, -10.0), np.full(3, 10.0)


def _stubs(monkeypatch, replay_target):
    """Observer residual: sharp across V, blind along it; replay residual: ``replay_target(t)`` is the point
    along V that the replay at time t prefers."""
    rng = np.random.default_rng(0)
    noise = rng.normal(size=N)
    g = np.stack([50 * np.cos(T), 50 * np.ones(N), 50 * np.cos(T)], axis=1)      # rows orthogonal to V
    g[:, 1] *= np.sin(3 * T)
    rec = types.SimpleNamespace(t_s=T)
    data = types.SimpleNamespace(recs=[types.SimpleNamespace(residual="observer", rec=rec)], name="observer")
    replay = types.SimpleNamespace(recs=data.recs, name="replay")

    def make_fun(spec, d, masks=None, with_current=True):
        m = np.ones(N, bool) if masks is None else masks[0]

        def fun(x):
            x = np.asarray(x, float)
            if d is replay:
                r = 20.0 * (V @ (x - X_TRUE) - replay_target(T)) * (1 + T)
            else:
                r = g @ (x - X_OBS) + noise
            return r[m]
        return fun

    monkeypatch.setattr(F, "make_fun", make_fun)
    monkeypatch.setattr(CT, "replay_view", lambda d: replay)
    fr = F.FitResult(spec=_Spec(), x=X_OBS.copy(), rss=float(noise @ noise), m=N, jac=None, nfev=0)
    return fr, data


def test_the_trade_the_observer_cannot_see_is_refitted_on_the_replay_where_both_halves_gain(monkeypatch):
    fr, data = _stubs(monkeypatch, lambda t: np.zeros_like(t))
    note = {"kept": False}                   # run.polish_replay's note: its whole replay refit not kept
    out = CT.refit_weak(fr, data, note=note)
    assert note["weak"]["kept"] and note["weak"]["directions"] == 1
    np.testing.assert_allclose(out.x, X_TRUE, atol=1e-3)           # moved along V only, to the replay's point
    assert note["weak"]["observer_cost"][1] == pytest.approx(note["weak"]["observer_cost"][0], rel=1e-6)


def test_a_weak_direction_the_halves_disagree_on_is_left_where_the_observer_put_it(monkeypatch):
    fr, data = _stubs(monkeypatch, lambda t: np.where(t < 3.0, 1.5, -1.5))
    note = {"kept": False}                   # run.polish_replay's note: its whole replay refit not kept
    out = CT.refit_weak(fr, data, note=note)
    assert not note["weak"]["kept"] and note["weak"]["rule"] == "halves refuse"
    assert out is fr


def test_nothing_happens_where_the_whole_replay_refit_was_kept(monkeypatch):
    fr, data = _stubs(monkeypatch, lambda t: np.zeros_like(t))
    note = {"kept": True}
    assert CT.refit_weak(fr, data, note=note) is fr and note == {"kept": True}
