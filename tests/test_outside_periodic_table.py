"""outside_series.periodic_table_series: generic tables that lose to the catalogue model, with an angle table that
passes its periodicity test without being significant, try the Fourier series of its period against the catalogue
model (round 34, u34ripple)."""
import math
from types import SimpleNamespace

from etb_gym.diagnose import outside_series as OS
from etb_gym.diagnose.unmodelled import GAIN_OUT, Generic

from test_outside_table_period import _Series


def _generic(periodic=True, significant=("unmodelled_speed",), heldout=4.32, period_deg=15.38, r2=0.75):
    shape = {"angle": {"periodic": periodic, "period_deg": period_deg, "periodic_r2": r2, "cycles": 5.5},
             "significant_terms": list(significant), "summary": "outside the catalogue: a friction torque ..."}
    return Generic(SimpleNamespace(tag="tables"), [], [], heldout, {}, {}, 0.040, shape)


def _run(monkeypatch, g, series, h_cat=3.14):
    calls = []
    monkeypatch.setattr(OS, "_series_from", lambda P, nominal, data, log: calls.append(P) or (series, None, P))
    monkeypatch.setattr(OS, "shortest_polished", lambda s, nominal, data, log: s)
    monkeypatch.setattr(OS, "_rms_deg", lambda spec, x, data: 0.035)
    return OS.periodic_table_series(g, h_cat, None, None, log=lambda *a: None), calls


def test_a_series_that_beats_the_catalogue_model_replaces_the_losing_tables(monkeypatch):
    """current_ripple 3B closed s47: tables 4.32, catalogue 3.14, table 15.38 deg at R2 0.75, series 0.895."""
    out, calls = _run(monkeypatch, _generic(), _Series(15.33, 0.895))
    assert calls == [15.38]
    assert out.series is not None and out.fit.tag == "series" and out.heldout == 0.895
    assert abs(OS.periodic_term(out.shape)["period_deg"] - 15.33) < 1e-9
    assert out.shape["summary"].startswith("outside the catalogue: a torque periodic in angle")


def test_the_tables_stay_when_the_series_does_not_beat_the_catalogue_by_the_margin(monkeypatch):
    h_cat = 3.14
    g = _generic()
    out, calls = _run(monkeypatch, g, _Series(15.33, (1.0 - GAIN_OUT) * h_cat * 1.01), h_cat)
    assert calls == [15.38] and out is g and out.series is None


def test_not_tried_without_a_periodic_table_or_where_the_tables_already_win(monkeypatch):
    for g in (_generic(periodic=False),                           # short of the periodicity test (R2, cycles)
              _generic(significant=("unmodelled_angle",)),         # a described period: with_series' job
              _generic(heldout=2.0)):                              # the tables win: the ordinary outside step
        out, calls = _run(monkeypatch, g, _Series(15.33, 0.5))
        assert calls == [] and out is g
    g = _generic()
    out, calls = _run(monkeypatch, g, _Series(15.33, 0.5), h_cat=math.inf)
    assert calls == [] and out is g


def _search(monkeypatch, residual):
    """outside_series._series_from with the fits replaced: held-out 4.6 for the angle alone, 24.9 per ampere, 3.81
    for both parts (detent_torque 3B closed s45); which parts' series are fitted, and the one kept."""
    held = {("angle",): 4.6, ("current",): 24.9, ("angle", "current"): 3.81}
    fitted = []

    def fit_series(nominal, data, P, parts, H, start=None, log=None, period_free=True, iters=0, heldout=True,
                   grown_from=None):
        fitted.append((tuple(parts), H))
        s = SimpleNamespace(parts=tuple(parts), harmonics=H, heldout=held[tuple(parts)] if heldout else math.inf,
                            component=SimpleNamespace(params=SimpleNamespace(period_rad=math.radians(P))),
                            fit=SimpleNamespace(rss=held[tuple(parts)] * (1.0 + 0.1 * (H == 6)), spec=parts, x=H))
        return s

    monkeypatch.setattr(OS, "scan_period", lambda nominal, data, P, H, log: P)
    monkeypatch.setattr(OS, "fit_series", fit_series)
    monkeypatch.setattr(OS, "Problem", SimpleNamespace(make=lambda spec, x, ids: spec))
    monkeypatch.setattr(OS, "heldout_error", lambda pf, data: held[pf])
    monkeypatch.setattr(OS, "_coefficients", lambda s: {})
    monkeypatch.setattr(OS, "subharmonic", lambda s, nominal, data, log: None)
    monkeypatch.setattr(OS, "reduced", lambda s, nominal, data, log: None)
    data = SimpleNamespace(recs=[SimpleNamespace(residual=residual)])
    best, sub, P = OS._series_from(24.56, None, data, log=lambda *a: None)
    return best, fitted


def test_a_closed_loop_series_keeps_one_part(monkeypatch):
    """In a closed loop the current follows the angle torque: the folds cannot tell a part per ampere from a part of
    the angle alone, so both parts are not fitted; an open loop still tries them."""
    best, fitted = _search(monkeypatch, "observer")
    assert ("angle", "current") not in [p for p, _ in fitted] and best.parts == ("angle",)
    best, fitted = _search(monkeypatch, "replay")
    assert ("angle", "current") in [p for p, _ in fitted] and best.parts == ("angle", "current")
