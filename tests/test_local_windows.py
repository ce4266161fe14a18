"""explain.local_windows / _window_down: a closed loop's mismatch confined to a short window (the loop's first
engagement from rest, the window holding the plate's first move) is judged where it lives (docs/diagnosis.md, method, step 3)."""
from types import SimpleNamespace as NS

import numpy as np

from etb_gym.diagnose import explain as E

N = 6000                     # 6 s at 1 kHz
T = np.arange(N) * 1e-3
WIN = (T >= 0.17) & (T <= 0.26)


def _residual(level_in_window: float, seed: int = 0) -> np.ndarray:
    r = np.random.default_rng(seed).standard_normal(N)
    r[WIN] *= level_in_window
    return r


def _data(residual: str, t_move: float = 0.21):
    angle = np.where(T < t_move, 3.0, 54.0)          # at rest, then the loop's first step
    rec = NS(n=N, t_s=T, angle_deg=angle)
    return NS(recs=[NS(rec=rec, residual=residual, noise_deg=0.0128, tol_deg=None)])


def test_a_closed_loops_engagement_window_is_found_and_judged_there(monkeypatch):
    res = {"old": _residual(3.5), "fit": _residual(1.0, 1), "bent": _residual(2.8, 2)}
    monkeypatch.setattr(E.F, "evaluate", lambda spec, data, x, with_current: res[x])
    fits = {k: NS(spec=None, x=k) for k in res}
    closed = _data("observer")
    masks = E.local_windows(fits["old"], closed)
    assert masks is not None
    m = masks[0]
    assert m[WIN].mean() > 0.8 and m[~WIN].mean() < 0.01          # the window, nothing else
    # the whole recording's RMS barely moves: the window is 1.5 % of it, so the RMS gate cannot see it ...
    assert np.sqrt(np.mean(res["fit"] ** 2) / np.mean(res["old"] ** 2)) > 0.9
    # ... but inside the window the excess over the noise goes ~11 -> ~0: halved
    assert E._window_down(fits["fit"], fits["old"], closed, masks)
    assert not E._window_down(fits["bent"], fits["old"], closed, masks)   # ~11 -> ~7: not halved
    # the same window away from the plate's first move from rest (a stop's contact, a sweep) is not this event
    assert E.local_windows(fits["old"], _data("observer", t_move=1.0)) is None


def test_no_local_windows_in_open_loop_or_at_the_noise(monkeypatch):
    res = {"old": _residual(3.5), "clean": _residual(1.0, 3)}
    monkeypatch.setattr(E.F, "evaluate", lambda spec, data, x, with_current: res[x])
    assert E.local_windows(NS(spec=None, x="old"), _data("replay")) is None      # replays: _excess_down's job
    assert E.local_windows(NS(spec=None, x="clean"), _data("observer")) is None  # nothing above 3x the floor
