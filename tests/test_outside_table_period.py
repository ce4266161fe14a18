"""outside_series.from_table_period: an outside description with no period gets a Fourier series started from the
angle table's own periodogram (round 33, s33ripple)."""
import math
from types import SimpleNamespace

from etb_gym.diagnose import outside_series as OS
from etb_gym.diagnose.unmodelled import Generic


class _Series:
    """What from_table_period reads of a Series."""

    def __init__(self, period_deg, heldout, parts=("current",)):
        self.component = SimpleNamespace(params=SimpleNamespace(period_rad=math.radians(period_deg)))
        self.heldout, self.parts = heldout, parts
        self.fit = SimpleNamespace(spec=None, x=None, tag="series")

    def describe(self):
        P = math.degrees(self.component.params.period_rad)
        return {"period_deg": P, "current_words": "proportional to the current", "words": f"a series of {P:.2f} deg"}


def _generic(period_deg=44.1, r2=0.95, periodic=False, heldout=1.19):
    shape = {"angle": {"periodic": periodic, "period_deg": period_deg, "periodic_r2": r2, "cycles": 1.5},
             "significant_terms": ["unmodelled_angle"] if periodic else [], "summary": "outside the catalogue: ..."}
    return Generic(SimpleNamespace(tag="tables"), [], [], heldout, {}, {}, 0.0339, shape)


def _run(monkeypatch, g, series):
    calls = []
    monkeypatch.setattr(OS, "_series_from", lambda P, nominal, data, log: calls.append(P) or (series, None, P))
    monkeypatch.setattr(OS, "shortest_polished", lambda s, nominal, data, log: s)
    monkeypatch.setattr(OS, "_rms_deg", lambda spec, x, data: 0.034)
    return OS.from_table_period(g, None, None, log=lambda *a: None), calls


def test_a_third_of_the_tables_period_replaces_the_tables(monkeypatch):
    """current_ripple random closed s43: table 44.1 deg, series 14.10 deg (1/3), held-out 0.903 against 1.19."""
    g = _generic()
    out, calls = _run(monkeypatch, g, _Series(14.10, 0.903))
    assert calls == [44.1]
    assert out.series is not None and out.fit.tag == "series" and out.heldout == 0.903 and out.heldout_tables == 1.19
    assert OS.periodic_term(out.shape)["period_deg"] == 14.10            # the period is now described
    assert out.shape["significant_terms"][0] == "unmodelled_current"


def test_the_tables_stay_when_the_period_is_no_harmonic(monkeypatch):
    out, _ = _run(monkeypatch, _generic(), _Series(17.5, 0.9))           # 44.1 / 17.5 = 2.52: neither 2 nor 3
    assert out.series is None and out.fit.tag == "tables" and OS.periodic_term(out.shape) is None


def test_the_tables_stay_when_the_series_predicts_the_folds_worse(monkeypatch):
    out, _ = _run(monkeypatch, _generic(heldout=1.0), _Series(14.7, 1.0 * (1 + OS.SERIES_TOL) * 1.01))
    assert out.series is None and out.fit.tag == "tables"


def test_not_tried_without_a_periodogram_or_with_a_period_described(monkeypatch):
    for g in (_generic(r2=0.2), _generic(period_deg=None), _generic(periodic=True)):
        out, calls = _run(monkeypatch, g, _Series(14.1, 0.5))
        assert calls == [] and out is g
