"""The coarse scan before a candidate's local fit (fit.scan_start): where it looks, and a case it rescues."""
import math

import numpy as np
import pytest

from etb_gym.diagnose import fit as F
from etb_gym.diagnose.candidates import CANDIDATES
from etb_gym.diagnose.model import Spec, prepare, restart_view
from etb_gym.diagnose.run import choose_substeps
from etb_gym.plant import make_plant
from scripts_loader import load_script


def test_scan_offsets_are_log_spaced_inside_the_bounds_on_each_side_with_room():
    d = F.scan_offsets(-100.0, 100.0)
    pos = sorted(x for x in d if x > 0)
    neg = sorted(-x for x in d if x < 0)
    assert pos == pytest.approx(neg) and len(pos) == F.SCAN_POINTS
    assert max(pos) == pytest.approx(100.0) and min(pos) >= F.SCAN_MIN
    assert all(b / a >= F.SCAN_RATIO - 1e-9 for a, b in zip(pos, pos[1:]))
    # a start on its lower bound (backlash's play cannot be negative) is scanned upwards only
    assert all(0 < x <= 18.7 for x in F.scan_offsets(1e-9, 18.7))
    assert F.scan_offsets(-0.1, 0.2) == []          # no room: nothing to scan, the local fit alone
    lo, hi = -1.33, 18.7
    assert all(lo <= x <= hi for x in F.scan_offsets(lo, hi))


def test_scan_finds_a_closed_loop_sensor_offset_the_local_fit_alone_misses():
    """Closed loop, 0.5 deg sensor offset, the reference closes the plate to the stop: the observer residual is
    steep in the offset where the plate meets the stop, so the screening fit (SCREEN_NFEV evaluations) from
    offset 0 may barely move (it did when this test was written; with numpy 2.4.6 / scipy 1.17.1 it reaches 0.505 deg);
    started from the scan's best point it lands near the truth's 0.5 deg, never worse than the local fit."""
    from etb_gym.diagnose.explain import SCREEN_NFEV, extend
    rec = load_script("scan_start_cases").offset_closed_recording(duration_s=2.6, offset_deg=0.5, noise_deg=0.01, seed=0)
    base = make_plant("3B")
    data = prepare([rec], base.supply.voltage_V, residual="observer")
    assert data.recs[0].residual == "observer"
    base = base.replace(substeps=choose_substeps(base, data))
    fd = restart_view(data)
    nom = F.calibrate(Spec(base), fd, max_nfev=40)
    spec = nom.spec.with_candidate(CANDIDATES["sensor_offset_gain"])
    x0 = extend(nom.x, spec)
    k = len(nom.x)                                   # the candidate's main parameter: offset_deg
    local = F.fit(spec, fd, x0, max_nfev=SCREEN_NFEV)
    scanned = F.fit(spec, fd, x0, max_nfev=SCREEN_NFEV, scan=k)
    off_local = local.values["sensor_offset_gain.offset_deg"]
    off_scan = scanned.values["sensor_offset_gain.offset_deg"]
    assert abs(off_scan - 0.5) < 0.15, off_scan
    assert scanned.rss <= 1.01 * local.rss, (scanned.rss, local.rss, off_local)
    if abs(off_local - 0.5) >= 0.15:     # where the local fit misses
        assert scanned.rss < 0.5 * local.rss, (scanned.rss, local.rss, off_local)
    assert scanned.rss < 0.5 * nom.rss
    n_profile = len(spec.nominal) + F.PROFILE_STEPS * 2 * F.SCAN_POINTS        # the profiled scan's evaluations
    assert math.isfinite(scanned.rss) and scanned.nfev <= local.nfev + 2 * F.SCAN_POINTS + n_profile + SCREEN_NFEV


def _collinear_residual(K=10.0, b_true=2.0, n=400):
    """r(a, b) = (a + K b + b^2 s) - (a_true + K b_true + b_true^2 s): to first order the candidate b does what
    the fitted a does (a free play: a spring preload shift), so at a = a_true + K b_true, b = 0 (the nominal fit
    that absorbed it) the Jacobian's columns are collinear and b alone only makes the fit worse."""
    s = np.sin(np.linspace(0.0, 12.0, n))
    y = 1.0 + K * b_true + b_true ** 2 * s

    def fun(x):
        return x[0] + K * x[1] + x[1] ** 2 * s - y
    fun.failure = None
    return fun, np.array([1.0 + K * b_true, 0.0])


def test_profiled_scan_finds_a_parameter_whose_first_order_effect_the_fitted_ones_already_carry():
    fun, x0 = _collinear_residual()
    lo, hi = np.array([-100.0, 0.0]), np.array([100.0, 10.0])
    r0 = fun(x0)
    plain, r_plain, _ = F.scan_start(fun, x0, r0, 1, lo, hi)
    prof, r_prof, n = F.scan_start(fun, x0, r0, 1, lo, hi, profile=[0])
    assert plain[1] == 0.0 and float(r_plain @ r_plain) == pytest.approx(float(r0 @ r0))   # the scan alone: stuck
    assert prof[1] > 0.5 and float(r_prof @ r_prof) < 0.6 * float(r0 @ r0), (prof, float(r_prof @ r_prof))
    assert n <= len(F.scan_offsets(lo[1] - x0[1] + 1e-9, hi[1] - x0[1] - 1e-9)) * (1 + F.PROFILE_STEPS) + 1


def test_observer_recordings_are_cross_validated_on_short_blocks_replays_on_long_ones():
    from types import SimpleNamespace as NS
    t = np.arange(0.0, 2.0, 0.001)
    phi = 40.0 + 40.0 * np.sin(2 * np.pi * 1.3 * t)          # every block sweeps the stroke
    data = NS(recs=[NS(rec=NS(t_s=t, angle_deg=phi), residual="observer"),
                    NS(rec=NS(t_s=t, angle_deg=phi), residual="replay")])
    A, B = F.fold_masks(data)
    for a, b, block in zip(A, B, (F.FOLD_BLOCK_OBSERVER_S, F.FOLD_BLOCK_S)):
        assert not np.any(a & b) and np.all(a | b)
        switches = np.flatnonzero(np.diff(a.astype(int))) + 1
        assert np.allclose(np.diff(t[switches]), block, atol=2e-3), block
    assert F.FOLD_BLOCK_OBSERVER_S < F.FOLD_BLOCK_S


def test_a_replay_whose_folds_would_not_see_the_plate_move_over_the_same_angles_gets_shorter_blocks():
    from types import SimpleNamespace as NS
    t = np.arange(0.0, 6.0, 0.001)
    u = (t % F.FOLD_BLOCK_S) / F.FOLD_BLOCK_S                     # one triangle per 0.5 s block
    odd = (np.floor(t / F.FOLD_BLOCK_S).astype(int) % 2) == 1
    phi = np.where(odd, 80.0, 20.0) * (1.0 - np.abs(2.0 * u - 1.0))  # odd blocks sweep 0-80 deg, even ones 0-20
    rd = NS(rec=NS(t_s=t, angle_deg=phi), residual="replay")
    assert F.fold_cover(rd, F.FOLD_BLOCK_S) < F.FOLD_COVER_MIN
    b = F.fold_block_s(rd)
    assert b in F.FOLD_BLOCKS_SHORT_S and F.fold_cover(rd, b) > 2 * F.fold_cover(rd, F.FOLD_BLOCK_S)
    assert F.fold_block_s(rd, 1.0) == 1.0                            # a block length asked for is kept
    still = NS(rec=NS(t_s=t, angle_deg=np.full(t.size, 5.0)), residual="replay")
    assert F.fold_cover(still, F.FOLD_BLOCK_S) == 1.0 and F.fold_block_s(still) == F.FOLD_BLOCK_S
    burst = NS(rec=NS(t_s=t, angle_deg=np.interp(t, [0.0, 0.05, 0.2, 6.0], [5.0, 5.0, 60.0, 60.0])), residual="replay")
    cover = F.fold_cover(burst, F.FOLD_BLOCK_S)                      # one sweep, in the first block
    assert cover < F.FOLD_COVER_MIN and all(F.fold_cover(burst, b) <= cover for b in F.FOLD_BLOCKS_SHORT_S)
    assert F.fold_block_s(burst) == F.FOLD_BLOCK_S                   # no shorter block sees more: kept


def _two_basins(a=(1.0, 0.0), b=(4.0, 6.0)):
    """A cost with two basins: near ``a`` it bottoms out at 1, near ``b`` at 0 (which basin: the nearer point)."""
    a, b = np.asarray(a), np.asarray(b)

    def fun(x):
        fun.calls += 1
        if np.sum((x - a) ** 2) < np.sum((x - b) ** 2):
            return np.array([x[0] - a[0], x[1] - a[1], 1.0])
        return np.array([x[0] - b[0], x[1] - b[1], 0.0])

    fun.failure, fun.calls = None, 0
    return fun


def test_multi_start_reaches_the_basin_that_a_start_of_the_second_parameter_opens():
    """A friction's fit stays in the basin it starts in (stribeck_friction@2 3B closed s13, round 21): with the
    second parameter started at 6 as well, the grid reaches the lower basin that a fit from 0 cannot."""
    from scipy.optimize import least_squares
    fun = _two_basins()
    lo, hi = np.array([-1.0, -1.0]), np.array([10.0, 10.0])
    x0 = np.zeros(2)
    plain = least_squares(fun, x0, bounds=(lo, hi))
    assert plain.cost > 0.4                                  # the fit from the start: the upper basin
    best, n = F.multi_start(fun, x0, 0, lo, hi, [6.0], 20, 0.03)
    assert best.cost < 1e-8 and np.allclose(best.x, [4.0, 6.0], atol=1e-4)
    assert n > 0 and fun.failure is None
    none, _ = F.multi_start(fun, x0, 0, lo, hi, [], 20, 0.03)  # without the second start: the grid of the first
    assert none is not None                                     # parameter alone still gives a fit


def test_stribeck_friction_declares_starts_of_its_stribeck_velocity_inside_its_bounds():
    from etb_gym.diagnose.candidates import CANDIDATES
    c = CANDIDATES["stribeck_friction"]
    p = c.fit[1]
    assert c.starts and all(p.lower < v < p.upper for v in c.starts)
    assert all(not k.starts for k in CANDIDATES.values() if k.id != "stribeck_friction")


def test_a_parameter_the_fold_does_not_see_goes_back_to_the_full_datas_value(monkeypatch):
    """fit.unseen_kept (cross-validation): a parameter whose Jacobian column on the fold's residual carries less
    than UNSEEN_SS (a stop the plate touched only in the other fold's blocks) returns to the full data's value
    before the other fold is scored, where that leaves the fold's own residual as it was; a seen one keeps the
    fold's value (no simulation: evaluate stands in)."""
    x0 = np.array([0.0, 0.0, 0.0])
    J = np.array([[3.0, 0.0, 0.0], [1.0, 1e-4, 0.0], [0.0, 0.0, 0.0]])    # parameters 1 and 2 not seen
    fr = F.FitResult(spec=None, x=np.array([0.4, -3.4, 0.0]), rss=10.0, m=3, jac=J, nfev=1)
    seen_rss = {}
    monkeypatch.setattr(F, "evaluate", lambda spec, data, x, masks=None: np.full(1, np.sqrt(seen_rss["v"])))
    seen_rss["v"] = 10.0
    np.testing.assert_array_equal(F.unseen_kept(None, None, fr, x0, None), [0.4, 0.0, 0.0])
    seen_rss["v"] = 12.0                      # the fold's own residual grows: the fold fit's values stand
    np.testing.assert_array_equal(F.unseen_kept(None, None, fr, x0, None), fr.x)
    fr_none = F.FitResult(spec=None, x=np.array([1.0]), rss=1.0, m=1, jac=None, nfev=1)
    np.testing.assert_array_equal(F.unseen_kept(None, None, fr_none, np.zeros(1), None), [1.0])
