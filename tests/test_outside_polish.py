"""outside_series.levenberg / polish: the kept Fourier series fitted on to convergence (round 29, d29outside)."""
import dataclasses

import numpy as np

from etb_gym.diagnose import outside_series as OS


@dataclasses.dataclass
class _Box:
    lo: np.ndarray
    hi: np.ndarray

    def bounds(self):
        return self.lo, self.hi


@dataclasses.dataclass
class _Problem:                      # what levenberg uses of a penalized.Problem
    spec: _Box
    x: np.ndarray
    free: np.ndarray

    def penalty(self, lams):
        return np.zeros((self.free.size, self.free.size))

    def pull(self, lams):
        return np.zeros(self.free.size)


def _phase_drift_problem():
    """A periodic signal over several cycles fitted in its period and amplitude from a start 4 % off in the
    period: output error steep in the period, as a series over a swept stroke; the full Gauss-Newton step
    overshoots there."""
    t = np.linspace(0.0, 6.0, 600)
    truth = (1.0, 1.0)

    def model(x):
        return x[0] * np.sin(2 * np.pi * t / x[1]) + 0.3 * x[0] * np.sin(4 * np.pi * t / x[1])

    y = model(truth)
    residual = lambda x: (model(x) - y) / 0.01               # noqa: E731  (noise units)

    def jacobian(pb, r, fd):
        h = fd * 1e-2
        J = np.empty((r.size, pb.free.size))
        for j, k in enumerate(pb.free):
            x = pb.x.copy()
            x[k] += h
            J[:, j] = (residual(x) - r) / h
        return J
    pb = _Problem(_Box(np.array([0.0, 0.5]), np.array([5.0, 2.0])), np.array([0.7, 1.04]), np.array([0, 1]))
    return pb, residual, jacobian


def test_levenberg_walks_out_of_a_phase_drift():
    pb, residual, jacobian = _phase_drift_problem()
    out, r, J, it, obj0, obj = OS.levenberg(pb, residual, jacobian)
    assert J is not None and it >= 1 and obj < 1e-3 * obj0
    assert abs(out.x[1] - 1.0) < 1e-3 and abs(out.x[0] - 1.0) < 1e-2
    assert np.allclose(r, residual(out.x))
    # the start is returned (no step accepted) when nothing lowers the objective
    at = dataclasses.replace(pb, x=np.array([1.0, 1.0]))
    same, _, _, it0, o0, o1 = OS.levenberg(at, residual, jacobian)
    assert it0 == 0 and o0 == o1 == 0.0 and np.array_equal(same.x, at.x)


def test_levenberg_stays_within_the_bounds():
    pb, residual, jacobian = _phase_drift_problem()
    pb = dataclasses.replace(pb, spec=_Box(np.array([0.0, 1.02]), np.array([5.0, 2.0])))
    out, *_ = OS.levenberg(pb, residual, jacobian)
    lo, hi = pb.spec.bounds()
    assert np.all(out.x >= lo) and np.all(out.x <= hi) and out.x[1] < 1.021


def test_polish_keeps_the_series_when_it_cannot_be_simulated(monkeypatch):
    """A failure inside the polish leaves the series as the search found it (with a message)."""
    from types import SimpleNamespace

    def boom(*a, **k):
        raise np.linalg.LinAlgError("singular")
    monkeypatch.setattr(OS, "levenberg", boom)
    monkeypatch.setattr(OS, "_coefficients", lambda s: {})
    monkeypatch.setattr(OS, "series_candidate", lambda *a, **k: None)
    monkeypatch.setattr(OS, "Problem", SimpleNamespace(make=lambda *a, **k: None))

    class _Spec:
        base, nominal, params = None, (), ()

        def with_candidate(self, c):
            return self
    monkeypatch.setattr(OS, "Spec", lambda *a: _Spec())
    s = SimpleNamespace(fit=SimpleNamespace(spec=_Spec(), x=np.zeros(0)), parts=("angle",), harmonics=3,
                        component=SimpleNamespace(params=SimpleNamespace(period_rad=0.3)))
    said = []
    assert OS.polish(s, None, said.append) is s
    assert said and "could not be fitted" in said[0]


def test_the_polished_series_of_the_shorter_period_is_kept_by_bic(monkeypatch):
    """outside_series.shortest_polished: a polished series that repeats with P / m is compared, by BIC, with the
    series of P / m, polished and grown (current_ripple 3B open s28: 45.11 deg kept by the folds before any
    polish; the polished 14.95 deg series won by BIC -2689, twin 26x -> 7.4x)."""
    import math
    from types import SimpleNamespace

    def series(P, H, bic, heldout=math.inf):
        return SimpleNamespace(harmonics=H, parts=("current",), heldout=heldout,
                               component=SimpleNamespace(params=SimpleNamespace(period_rad=math.radians(P))),
                               fit=SimpleNamespace(bic=lambda: bic, rss=1.0))
    long = series(45.0, 6, -400.0, heldout=8.8)
    bics = {(15.0, 2): -2700.0, (15.0, 3): -2900.0, (15.0, 6): -2880.0}
    polished = []
    monkeypatch.setattr(OS, "polish", lambda s, data, log: polished.append(s.harmonics) or s)
    monkeypatch.setattr(OS, "_coefficients", lambda s: {})
    monkeypatch.setattr(OS, "model_current_rms", lambda s, data: 1.0)
    monkeypatch.setattr(OS, "reductions", lambda c, H, P, parts, i: [(3, H // 3, {})])
    monkeypatch.setattr(OS, "fit_series", lambda nominal, data, P, parts, H, start, log, **kw:
                        series(round(P, 6), H, bics[(round(P, 6), H)]))
    quiet = lambda *a: None  # noqa: E731
    s = OS.shortest_polished(long, None, None, quiet)
    assert s.harmonics == 3 and s.heldout == 8.8          # grown to 3 (BIC lower), 6 not (higher than 3's)
    assert polished == [6, 2, 3, 6]
    bics.update({(15.0, 2): -300.0, (15.0, 3): -300.0, (15.0, 6): -300.0})
    assert OS.shortest_polished(long, None, None, quiet) is long    # the longer series fits better: it stays
